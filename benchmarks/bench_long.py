"""L1: records of the sizes users bring, made by `bsfs synth`, identified cold.

Each `bsfs` run is a fresh process with an empty compilation cache (cold) and, for the
identifications, again with the cache it filled (warm); wall seconds and the process's
peak memory (its own high-water mark). The records are generated here into a temporary
folder (seeded), never committed:

- a 60 s random-excitation record at 25.6 kHz (1.5 M samples) plus six 10 s stepped sines
  (100, 120, 150, 200, 300, 500 Hz);
- a 120 s burst chirp at 51.2 kHz (6.1 M samples);
- FRFs of 65 536 lines in CSV and in UFF58 (the default drive's linear model with 1 %
  noise on each line);
- random records of 7.5, 15, 30 and 60 s at 25.6 kHz: peak memory against length.

Usage: python benchmarks/bench_long.py [--quick]   (--quick: shorter records, a smoke run)
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))

from _cli import CLI, ROOT, env, write_result  # noqa: E402
from _machine import machine_info, machine_line  # noqa: E402

PRELOADS = "nut_preload,bearing_preload,c_b,c_s,c_n"


def bsfs(args, cache):
    """`bsfs ARGS` in a fresh process: (wall seconds, peak memory MB). The peak is the
    child's own high-water mark, read with `os.wait4` (the command ends with `os._exit`,
    so no exit hook of its own could report it)."""
    with tempfile.TemporaryFile() as out:
        t0 = time.perf_counter()
        proc = subprocess.Popen([sys.executable, "-c", CLI, *args], stdout=out, stderr=out,
                                env=env(cache), cwd=ROOT)
        _, status, usage = os.wait4(proc.pid, 0)
        wall = time.perf_counter() - t0
        proc.returncode = code = os.waitstatus_to_exitcode(status)
        if code not in (0, 4):
            out.seek(0)
            raise SystemExit(f"bsfs {' '.join(args)} failed ({code}):\n"
                             f"{out.read().decode(errors='replace')[-3000:]}")
    peak_mb = usage.ru_maxrss / 1024.0
    print(f"  bsfs {' '.join(args)}: {wall:.1f} s, {peak_mb:.0f} MB", flush=True)
    return wall, peak_mb


def model_frf(path: Path, n_lines: int) -> None:
    import jax

    jax.config.update("jax_enable_x64", True)
    import numpy as np

    sys.path.insert(0, str(ROOT))  # the source tree that the commands run

    import bsfs_jax
    import identification as idn

    f = np.linspace(50.0, 2500.0, n_lines)
    system = bsfs_jax.build_system(bsfs_jax.preset("default"))
    acc = -((2 * np.pi * f) ** 2) * np.asarray(bsfs_jax.linear_frf(system, f))[:, 2]
    std = 0.01 * np.abs(acc)
    rng = np.random.default_rng(65536)
    noisy = acc + std * (rng.standard_normal(n_lines) + 1j * rng.standard_normal(n_lines))
    frf = idn.FrfRecord(f, noisy, np.stack([std**2, std**2], axis=1), None, 10, 2000.0, 20.0,
                        {"force_level": "rms"}, str(path.with_suffix("")), "random", 20.0)
    (idn.write_frf_csv if path.suffix == ".csv" else idn.write_frf_uff)(path, frf)


def identify_pair(records, tmp, tag, cache_root):
    cache = cache_root / tag
    out = {}
    for kind in ("cold", "warm"):
        wall, peak = bsfs(["identify", *map(str, records), "--fit", PRELOADS, "--out",
                           str(tmp / f"{tag}_{kind}")], cache)
        out[kind] = dict(wall_s=wall, peak_mb=peak)
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true")
    args = ap.parse_args(argv)
    scale = 0.125 if args.quick else 1.0
    t_start = time.perf_counter()
    rows, memory = [], []
    with tempfile.TemporaryDirectory() as d:
        tmp = Path(d)
        caches = tmp / "caches"

        def synth(name, *extra):
            path = tmp / name
            wall, peak = bsfs(["synth", "--preset", "default", *extra, "--out", str(path)],
                              caches / f"synth_{name}")
            return path, wall, peak

        # 1. 60 s random at 25.6 kHz plus six 10 s sines
        dur = 60.0 * scale
        rnd, w, p = synth("random60.csv", "--excitation", "random", "--start", "50", "--stop",
                          "2500", "--duration", f"{dur:g}", "--sample-rate", "25600",
                          "--force", "20", "--seed", "1")
        synth_rows = [(f"random {dur:g} s at 25.6 kHz", w, p)]
        sines = []
        for k, f in enumerate((100, 120, 150, 200, 300, 500)):
            path, w, p = synth(f"sine{f}.csv", "--frequency", str(f), "--force", "100",
                               "--duration", f"{10 * scale:g}", "--sample-rate", "25600",
                               "--seed", str(10 + k))
            sines.append(path)
            synth_rows.append((f"sine {f} Hz, {10 * scale:g} s at 25.6 kHz", w, p))
        r = identify_pair([rnd, *sines], tmp, "random_sines", caches)
        rows.append(dict(case=f"{dur:g} s random at 25.6 kHz + six {10 * scale:g} s sines",
                         samples=int(dur * 25600 + 6 * 10 * scale * 25600), **r,
                         target_s=60, target_mb=3000))
        # 2. 120 s chirp at 51.2 kHz
        dur = 120.0 * scale
        chirp, w, p = synth("chirp120.csv", "--excitation", "chirp", "--start", "50",
                            "--stop", "2500", "--duration", f"{dur:g}", "--sample-rate",
                            "51200", "--force", "5", "--seed", "2")
        synth_rows.append((f"chirp {dur:g} s at 51.2 kHz", w, p))
        r = identify_pair([chirp], tmp, "chirp", caches)
        rows.append(dict(case=f"{dur:g} s chirp at 51.2 kHz", samples=int(dur * 51200), **r,
                         target_s=120, target_mb=4000))
        # 3. 65 536-line FRFs
        n_lines = int(65536 * scale)
        for suffix in (".csv", ".uff"):
            path = tmp / f"frf{suffix}"
            model_frf(path, n_lines)
            r = identify_pair([path], tmp, f"frf{suffix[1:]}", caches)
            rows.append(dict(case=f"FRF of {n_lines} lines ({suffix[1:].upper()})",
                             samples=None, **r, target_s=60, target_mb=None))
        # 4. peak memory against length
        for sec in (7.5, 15.0, 30.0, 60.0):
            sec = sec * scale
            if abs(sec - 60.0 * scale) < 1e-9:
                path = rnd
            else:
                path, _, _ = synth(f"random{sec:g}.csv", "--excitation", "random", "--start",
                                   "50", "--stop", "2500", "--duration", f"{sec:g}",
                                   "--sample-rate", "25600", "--force", "20", "--seed", "3")
            wall, peak = bsfs(["identify", str(path), "--fit", PRELOADS, "--out",
                               str(tmp / f"mem{sec:g}")], caches / "memory")
            memory.append(dict(seconds=sec, samples=int(sec * 25600), wall_s=wall,
                               peak_mb=peak))
    info = machine_info()
    result = dict(machine=info, quick=args.quick, identify=rows,
                  synth=[dict(record=a, wall_s=b, peak_mb=c) for a, b, c in synth_rows],
                  memory=memory, seconds=time.perf_counter() - t_start)
    write_result("long_records_quick" if args.quick else "long_records", result,
                 markdown(result))
    return 0


def _met(value, target):
    if target is None or value is None:
        return "–"
    return "met" if value <= target else "**not met**"


def markdown(res) -> str:
    m = res["machine"]
    lines = ["## L1 Long records", "",
             "Command: `python benchmarks/bench_long.py`" + (" --quick" if res["quick"] else "")
             + " (records made by `bsfs synth`, seeded, in a temporary folder).",
             machine_line(m), "",
             "`bsfs identify RECORDS --fit " + PRELOADS + "` in a fresh process: cold with "
             "an empty compilation cache, warm with the cache the cold run filled; peak "
             "memory is the process's high-water mark. FRFs of more than 32 768 lines are "
             "fitted on merged runs of adjacent lines (`--max-lines`).", "",
             "| record(s) | samples | cold wall | cold peak memory | warm wall | target | "
             "time | memory |", "|---|---|---|---|---|---|---|---|"]
    for r in res["identify"]:
        target = f"<= {r['target_s']} s" + (f", <= {r['target_mb'] / 1000:g} GB"
                                            if r["target_mb"] else "")
        lines.append(
            f"| {r['case']} | {'–' if r['samples'] is None else format(r['samples'], ',')} | "
            f"{r['cold']['wall_s']:.1f} s | {r['cold']['peak_mb']:.0f} MB | "
            f"{r['warm']['wall_s']:.1f} s | {target} | {_met(r['cold']['wall_s'], r['target_s'])}"
            f" | {_met(r['cold']['peak_mb'], r['target_mb'])} |")
    lines += ["", "`bsfs synth` of each record (cold):", "",
              "| record | wall | peak memory |", "|---|---|---|"]
    lines += [f"| {s['record']} | {s['wall_s']:.1f} s | {s['peak_mb']:.0f} MB |"
              for s in res["synth"]]
    lines += ["", "Peak memory of `bsfs identify` against the length of a random record at "
              "25.6 kHz (the cache warm from the previous length):", "",
              "| length | samples | wall | peak memory | MB per million samples above the "
              "shortest |", "|---|---|---|---|---|"]
    base = res["memory"][0]
    for r in res["memory"]:
        extra = ("–" if r is base else
                 f"{(r['peak_mb'] - base['peak_mb']) / ((r['samples'] - base['samples']) / 1e6):.0f}")
        lines.append(f"| {r['seconds']:g} s | {r['samples']:,} | {r['wall_s']:.1f} s | "
                     f"{r['peak_mb']:.0f} MB | {extra} |")
    return "\n".join(lines) + "\n"


if __name__ == "__main__":
    sys.exit(main())
