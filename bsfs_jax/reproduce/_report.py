"""`reproduce(out_dir)`: run every experiment, save the figures, write REPRODUCTION.md.

The Markdown itself is rendered in `_markdown.py`; this module computes, judges the claims and
writes the files (figures, REPRODUCTION.md, reproduction.json).
"""

import dataclasses
import json
from pathlib import Path

import numpy as np

from .._files import jsonable, save_figure, write_bytes_atomic, write_text_atomic
from ..params import preset as load_preset
from . import _figures as figs
from ._claims import (
    CLAIMS,
    NOT_CHECKABLE,
    judge_increase,
    judge_monotone_growth,
    judge_motion,
    judge_preload_optimum,
)
from ._judge import (
    judge_angles,
    judge_chaos_all,
    judge_diameters,
    judge_nut_balls,
    verified_summary,
)
from ._markdown import _um, evidence_text, render_markdown
from ._markdown import motion_table_lines as motion_table_lines
from ._markdown import why_labels_differ as why_labels_differ
from ._run import (
    MOTION_CASES,
    PRELOADS_N,
    SPEEDS_RPM,
    ReproduceSettings,
    Reproduction,
    Timer,
    diameter_experiments,
    exciter_experiments,
    motion_experiments,
    thermal_experiments,
)
from ._run_sweeps import VERIFIED_SWEEPS, sweep_experiments

#: Output file of each figure, in the paper's order.
FIGURE_FILES = {
    "fig10_12": "fig10-12_exciter_100N.png",
    "fig13": "fig13_thermal_deformation.png",
    "fig14": "fig14_speed_time_history.png",
    "fig15": "fig15_speed_phase.png",
    "fig16": "fig16_preload_time_history.png",
    "fig17": "fig17_preload_phase.png",
    "fig18": "fig18_500Hz_5000N.png",
    "fig19": "fig19_1082Hz_5000N.png",
    "fig20": "fig20_382Hz_5000N.png",
    "fig21": "fig21_636.6Hz_5000N.png",
    "fig22": "fig22_waterfall_bearing_ball_diameter.png",
    "fig23": "fig23_waterfall_nut_ball_diameter.png",
    "fig24": "fig24_bifurcation_bearing_balls.png",
    "fig25": "fig25_bifurcation_nut_balls.png",
    "fig26": "fig26_frc_bearing_contact_angle.png",
    "fig27": "fig27_frc_nut_contact_angle.png",
}


def _save(fig, path: Path) -> None:
    import matplotlib.pyplot as plt

    save_figure(fig, path, dpi=110)
    plt.close(fig)


def reproduce(out_dir, settings: ReproduceSettings | None = None, *,
              progress: bool = False, log=None) -> Reproduction:
    """Compute analogues of the paper's Figs. 10-27 and write them with REPRODUCTION.md.

    **Arguments:**
    - `out_dir`: folder for the PNG figures, `REPRODUCTION.md` and `reproduction.json`.
    - `settings`: `ReproduceSettings` (default: the full run on the "paper-tuned" preset;
      `ReproduceSettings.quick_settings()` for a one-minute smoke run).
    - `progress`: progress bars for the sweeps; `log`: callable(str) for stage messages.

    **Returns:** a `Reproduction` (rows of the claims table, the numbers, figure paths).
    """
    s = settings or ReproduceSettings()
    say = log or (lambda msg: None)
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    params = load_preset(s.preset)
    default = load_preset("default")
    timer = Timer()
    paths = {k: out / v for k, v in FIGURE_FILES.items()}
    numbers: dict = {}
    rows: dict = {}

    say("Figs. 13-17: thermal deformation, speed and preload")
    thermal, tr = thermal_experiments(params, s)
    numbers["thermal"] = thermal
    if s.preset != "default" and not s.quick:
        numbers["thermal_default_preset"], _ = thermal_experiments(default, s)
    cond = f"{thermal['force_n']:g} N at {thermal['frequency_hz']:g} Hz, preset '{s.preset}'"
    _save(figs.compare_figure({"with thermal deformation": tr["thermal"],
                               "without thermal deformation": tr["no_thermal"]},
                              title=f"Fig. 13 analogue: nut response with / without thermal "
                              f"deformation ({cond}, 2000 r/min)"), paths["fig13"])
    speed_trajs = {f"n = {n:.0f} r/min": tr[f"speed_{n:.0f}"] for n in SPEEDS_RPM}
    pre_trajs = {f"F_p = {fp:.0f} N": tr[f"preload_{fp:.0f}"] for fp in PRELOADS_N}
    _save(figs.compare_figure(speed_trajs, kind="time", title=f"Fig. 14 analogue: time history "
                              f"at three screw speeds ({cond})"), paths["fig14"])
    _save(figs.compare_figure(speed_trajs, kind="phase", title=f"Fig. 15 analogue: phase "
                              f"portrait at three screw speeds ({cond})"), paths["fig15"])
    _save(figs.compare_figure(pre_trajs, kind="time", title=f"Fig. 16 analogue: time history "
                              f"at three nut preloads ({cond}, 2000 r/min)"), paths["fig16"])
    _save(figs.compare_figure(pre_trajs, kind="phase", title=f"Fig. 17 analogue: phase "
                              f"portrait at three nut preloads ({cond}, 2000 r/min)"),
          paths["fig17"])
    timer.lap("Figs. 13-17 (thermal)")

    say("Figs. 18-21: motion at 500 / 1082 / 382 / 636.6 Hz, 5000 N")
    motion, mtr = motion_experiments(params, s)
    numbers["motion"] = motion
    if s.preset != "default" and not s.quick:
        numbers["motion_default_preset"], _ = motion_experiments(default, s)
    for key, f, _, _ in MOTION_CASES:
        m = motion[key]
        title = (f"Fig. {key[3:]} analogue: f = {f:g} Hz, F = {s.force_n:g} N, preset "
                 f"'{s.preset}': verified {m['verified_motion']} (after "
                 f"{m['transient_periods']} periods: {m['motion']}), amplitude "
                 f"{_um(m['amplitude_m'])} um, lambda T = {m['lyapunov_per_period']:+.3f}")
        _save(figs.motion_figure(mtr[key], title=title), paths[key])
    timer.lap("Figs. 18-21 (motion types)")

    say("Figs. 22-23: spectra against ball diameter")
    diam = diameter_experiments(params, s)
    numbers["diameters"] = diam
    for key, name, who in (("fig22", "bearing.ball_diameter_mm", "bearing"),
                           ("fig23", "nut.ball_diameter_mm", "nut")):
        _save(figs.waterfall_figure(
            diam[name], param_label=f"{who} ball diameter [mm]",
            title=f"Fig. {key[3:]} analogue: spectrum of x_n vs {who} ball diameter "
                  f"({s.force_n:g} N at {s.waterfall_frequency_hz:g} Hz, preset '{s.preset}')"),
            paths[key])
    timer.lap("Figs. 22-23 (ball diameters)")

    say("Figs. 24-27: up/down frequency sweeps of ball counts and contact angles")
    sweeps = sweep_experiments(params, s, progress=progress, cache_dir=out / "sweeps")
    grid = (f"{s.force_n:g} N, {s.sweep_start_hz:g}-{s.sweep_stop_hz:g} Hz, "
            f"{s.sweep_points} points up and down, preset '{s.preset}'")
    for key in ("fig24", "fig25"):
        sw = sweeps[key]
        _save(figs.bifurcation_figure(sw["results"], label=sw["label"], unit=sw["unit"],
                                      title=f"Fig. {key[3:]} analogue: bifurcation diagrams "
                                      f"for {sw['label']} ({grid})"), paths[key])
    for key in ("fig26", "fig27"):
        sw = sweeps[key]
        _save(figs.frc_figure(sw["results"], label=sw["label"], unit=sw["unit"],
                              title=f"Fig. {key[3:]} analogue: frequency-response curves for "
                              f"{sw['label']} ({grid})"), paths[key])
    unique = {id(r): r for sw in sweeps.values() for r in sw["results"].values()}
    cached = sum(bool(r.metadata.get("loaded_from_cache")) for r in unique.values())
    timer.lap(f"Figs. 24-27 (sweeps; {cached} of {len(unique)} sweeps loaded from "
              f"{out / 'sweeps'} instead of computed)" if cached else "Figs. 24-27 (sweeps)")

    say("Figs. 10-12: 100 N exciter (model side)")
    exc, etr = exciter_experiments(params, s)
    numbers["exciter"] = exc
    _save(figs.exciter_figure(etr, title=f"Figs. 10-12 analogue (model only): worktable "
                              f"acceleration under 100 N, preset '{s.preset}'"),
          paths["fig10_12"])
    timer.lap("Figs. 10-12 (exciter)")

    # -- the claims table ------------------------------------------------------------------
    runs = thermal["runs"]
    rows["fig13"] = judge_increase(runs["thermal"]["amplitude_m"],
                                   runs["no_thermal"]["amplitude_m"])
    rows["fig14_15"] = judge_monotone_growth(
        [runs[f"speed_{n:.0f}"]["amplitude_m"] for n in SPEEDS_RPM], [37.04, 41.84, 60.48])
    rows["fig16_17"] = judge_preload_optimum(
        [runs[f"preload_{fp:.0f}"]["amplitude_m"] for fp in PRELOADS_N])
    rows.update(motion_claim_rows(motion))
    rows["fig22_23"] = judge_diameters(diam)
    summaries = {key: {v: verified_summary(r) for v, r in sweeps[key]["results"].items()}
                 for key in VERIFIED_SWEEPS}
    numbers["sweep_motions"] = summaries
    for key, judge in (("fig24", judge_chaos_all), ("fig25", judge_nut_balls)):
        rows[key] = judge(summaries[key])
    v26, why26, n26 = judge_angles(sweeps["fig26"]["results"], rising_expected=True,
                                   secondary={30.0: 1200.0, 40.0: 1500.0},
                                   mode_hz=sweeps["fig26"]["mode_hz"])
    v27, why27, n27 = judge_angles(sweeps["fig27"]["results"], rising_expected=False,
                                   secondary={50.0: 1460.0})
    step = (s.sweep_stop_hz - s.sweep_start_hz) / max(s.sweep_points - 1, 1)
    grid_note = (f" (frequency grid {step:.0f} Hz: a fold between two grid points shows no "
                 "hysteresis)")
    rows["fig26"], rows["fig27"] = (v26, why26 + grid_note), (v27, why27 + grid_note)
    numbers["frc"] = {"fig26": n26, "fig27": n27}
    # The cold starts of Figs. 18-21 land on one branch; where the FRC is multivalued the
    # continued sweeps of the unchanged preset show the other one.
    base = sweeps["fig24"]["results"][16.0]
    branches = {}
    for key, f, _, _ in MOTION_CASES:
        i = int(np.argmin(np.abs(base.values - f)))
        branches[key] = {"grid_hz": float(base.values[i]),
                         "up_m": float(base.amplitude[base.direction_index("up"), i, 2]),
                         "down_m": float(base.amplitude[base.direction_index("down"), i, 2])}
    numbers["motion_branches"] = branches
    acc = " / ".join(f"{exc[k]['acceleration_amplitude_m_s2']:.3f}" for k in ("100", "120", "150"))
    rows["fig10_12"] = (NOT_CHECKABLE, (
        f"model acceleration amplitude {acc} m/s^2 at 100/120/150 Hz; the paper's measured "
        "records are not available, so agreement cannot be checked here (the bundled "
        "data/paper-test records are synthetic)"))
    table = [{"key": c.key, "figures": c.figures, "condition": c.condition, "paper": c.paper,
              "verdict": rows[c.key][0], "this_model": rows[c.key][1]} for c in CLAIMS]
    numbers["timings_s"] = dict(timer.stages)
    numbers["chain_stiffness_n_per_m"] = chain_stiffness(params)
    rep = Reproduction(out, table, numbers, {k: str(p) for k, p in paths.items()},
                       dict(timer.stages), s)
    write_text_atomic(out / "REPRODUCTION.md", render_markdown(rep, params, default))
    write_bytes_atomic(out / "reproduction.json",
                       (json.dumps(jsonable({"rows": table, "numbers": numbers,
                                             "settings": dataclasses.asdict(s)},
                                            omit=_is_sweep_result),  # summarised elsewhere
                                   indent=1) + "\n").encode())
    return rep


def motion_claim_rows(motion: dict) -> dict:
    """Claims rows of Figs. 18-21: judged on the verified label (its amplitude where the
    verifier found an orbit), with the fixed-transient label beside it."""
    rows = {}
    for key, _, label, amp in MOTION_CASES:
        if key not in motion:
            continue
        m = motion[key]
        kind = label if label in ("quasi-periodic", "chaotic") else "periodic"
        found = m["verified_motion"] if m.get("verified") or m["verified_motion"] in (
            "unresolved", "failed") else "unresolved"
        found_kind = "periodic" if found.startswith("period-") else found
        a = m.get("verified_amplitude_m", float("nan"))
        a = a if np.isfinite(a) else m["amplitude_m"]
        v, why = judge_motion(found_kind, found, kind, label, a, amp,
                              reason=m.get("verify_reason", ""))
        why = "verified " + why
        why += (f" ({evidence_text(m)}); fixed-transient label after "
                f"{m['transient_periods']} periods: '{m['motion']}'")
        rows[key] = (v, why)
    return rows


def chain_stiffness(params) -> float:
    """Static stiffness [N/m] seen by the nut: 1 / (K^-1)_nn of the linearised system."""
    from ..machine import modes

    k = np.asarray(modes(params).stiffness)
    return float(1.0 / np.linalg.inv(k)[2, 2])


def _is_sweep_result(obj) -> bool:
    return hasattr(obj, "directions") and hasattr(obj, "summary")
