"""`reproduce(out_dir)`: run every experiment, save the figures, write REPRODUCTION.md."""

import dataclasses
import datetime
import io
import json
import platform
from pathlib import Path

import numpy as np

from .._files import jsonable, write_bytes_atomic, write_text_atomic
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
    UNRESOLVED_MAX,
    _fmt_hz,
    describe_candidates,
    judge_angles,
    judge_chaos_all,
    judge_diameters,
    judge_nut_balls,
    verified_summary,
)
from ._run import (
    MOTION_CASES,
    PRELOADS_N,
    SPEEDS_RPM,
    VERIFIED_SWEEPS,
    ReproduceSettings,
    Timer,
    diameter_experiments,
    exciter_experiments,
    motion_experiments,
    sweep_experiments,
    thermal_experiments,
)

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


@dataclasses.dataclass
class Reproduction:
    """What `reproduce` produced: the claims table rows, numbers, figure paths, timings."""

    out_dir: Path
    rows: list
    numbers: dict
    figures: dict
    timings: dict
    settings: ReproduceSettings

    @property
    def report_path(self) -> Path:
        return self.out_dir / "REPRODUCTION.md"


def _save(fig, path: Path) -> None:
    import matplotlib.pyplot as plt

    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=110, bbox_inches="tight")
    write_bytes_atomic(path, buf.getvalue())
    plt.close(fig)


def _um(x) -> str:
    return f"{x * 1e6:.1f}"


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


def evidence_text(m: dict) -> str:
    """The verified label's evidence: orbit residual and max |mu| for period-n, lambda T
    with its 95 % interval for the others, the reason for unresolved points."""
    label = m.get("verified_motion", "failed")
    if label.startswith("period-") and m.get("verified"):
        return (f"orbit residual {m['orbit_residual']:.1e}, max abs(mu) "
                f"{m['max_multiplier']:.4f}, lambda T = "
                f"{m['verified_lyapunov_per_period']:+.4f}")
    if label in ("chaotic", "quasi-periodic") and m.get("verified"):
        text = (f"lambda T = {m['verified_lyapunov_per_period']:+.4f} in "
                f"[{m['lyapunov_low']:+.4f}, {m['lyapunov_high']:+.4f}] (95 %), line fraction "
                f"{m['verified_line_fraction']:.3f}")
        if label == "quasi-periodic":
            text += (f", rotation number {m['rotation_number']:.4f}, curve error "
                     f"{m['curve_error']:.3f}")
        return text
    return m.get("verify_reason", "") or "no evidence"


def why_labels_differ(m: dict) -> str:
    """Why the fixed-transient label and the verified one differ (or that they agree)."""
    left = m.get("free_vibration_left", float("nan"))
    n, f = m["transient_periods"], m["frequency_hz"]
    sigma = m.get("decay_rate_per_s", float("nan"))
    decay = (f"exp(-sigma t) = {left:.2g} (sigma = {sigma:.1f} 1/s, t = {n} / {f:g} Hz = "
             f"{n / f * 1e3:.0f} ms)")
    found, cand = m.get("verified_motion", "failed"), m["motion"]
    if found == cand and m.get("verified"):
        return f"they agree; the {n}-period transient leaves {decay} of the free vibration"
    if found in ("unresolved", "failed"):
        return f"the verifier found no evidence for any label ({found})"
    if found == "period-1" and left > 1e-3:
        return (f"the {n}-period samples still hold the first mode's free vibration: {decay} "
                "of it remains, so they do not repeat; Newton on the period map finds the "
                "stable orbit they approach")
    if found == "period-1":
        return (f"'{cand}' is read from the samples alone (their repetition tolerance, "
                f"lambda T over {m.get('record_periods', '?')} periods); the orbit found "
                f"from them is stable and they approach it ({decay} of the free vibration "
                "left)")
    return (f"the samples after {n} periods read '{cand}'; the verifier's evidence says "
            f"{found}")


def motion_table_lines(motion: dict, transient_periods: int) -> list:
    """The motion table of Figs. 18-21: fixed-transient label beside the verified one."""
    L = [f"| Fig. | f [Hz] | paper | fixed-transient label ({transient_periods} periods) | "
         "verified label | amplitude [um] | evidence | why they differ |",
         "|---|---|---|---|---|---|---|---|"]
    for key, f, label, amp in MOTION_CASES:
        if key not in motion:
            continue
        m = motion[key]
        va = m.get("verified_amplitude_m", float("nan"))
        amp_text = _um(va) if np.isfinite(va) else _um(m["amplitude_m"])
        cand = m["motion"] + (f" (reading: {m['reading']})" if m["reading"] != m["motion"]
                              else "")
        L.append(f"| {key[3:]} | {f:g} | {label}, {amp * 1e6:.1f} um | {cand} | "
                 f"**{m['verified_motion']}** | {amp_text} | {_cell(evidence_text(m))} | "
                 f"{_cell(why_labels_differ(m))} |")
    return L


def _cell(text: str) -> str:
    """Text for a markdown table cell (a '|' would end the cell)."""
    return str(text).replace("|", "\\|")


def chain_stiffness(params) -> float:
    """Static stiffness [N/m] seen by the nut: 1 / (K^-1)_nn of the linearised system."""
    from ..machine import modes

    k = np.asarray(modes(params).stiffness)
    return float(1.0 / np.linalg.inv(k)[2, 2])


def _is_sweep_result(obj) -> bool:
    return hasattr(obj, "directions") and hasattr(obj, "summary")


def _tuning_lines(params, default) -> list:
    """The keys whose values differ from the default preset (what was tuned)."""
    a, b = params.to_dict(), default.to_dict()
    lines = []
    for section, values in a.items():
        for key, v in values.items():
            w = b.get(section, {}).get(key)
            if w != v:
                lines.append(f"| `{section}.{key}` | {w} | {v} |")
    return lines


def render_markdown(rep: Reproduction, params, default) -> str:
    s, n = rep.settings, rep.numbers
    runs = n["thermal"]["runs"]
    L = []
    L.append("# Reproduction of Yang et al. (2022), Section 3, with this model\n")
    L.append(f"Generated by `bsfs reproduce` on {datetime.date.today().isoformat()} "
             f"({platform.machine()}, Python {platform.python_version()}); "
             + ("QUICK run: coarse grids and short horizons, numbers are indicative only"
                if s.quick else "full run")
             + f"; total {sum(rep.timings.values()):.0f} s.\n")
    L.append("The paper gives no parameter table, so its numbers cannot be matched exactly. "
             "Every row below states what *this* model computes with the stated parameters "
             "and excitation, and a verdict: **reproduced** (the paper's qualitative result "
             "holds, and for single numbers within 25 %), **partly** (the trend or the kind "
             "of motion holds, not the rest), **not reproduced**, or **not checkable**. The "
             "verdicts are computed by rules written in `bsfs_jax/reproduce/_claims.py` and "
             "`_judge.py`, not typed by hand.\n")
    L.append("## Claims table (physics.md section 6)\n")
    L.append("| Fig. | Condition | Paper | This model | Verdict |")
    L.append("|---|---|---|---|---|")
    for r in rep.rows:
        L.append(f"| {r['figures']} | {r['condition']} | {r['paper']} | "
                 f"{_cell(r['this_model'])} | "
                 f"**{r['verdict']}** |")
    L.append("")
    L.append("## Parameters and excitation\n")
    L.append(f"Preset **`{s.preset}`**. Differences from physics.md's `default` preset:\n")
    tl = _tuning_lines(params, default)
    if tl:
        L.append("| key | default | used here |")
        L.append("|---|---|---|")
        L.extend(tl)
    else:
        L.append("(none: physics.md defaults)")
    L.append("")
    th = runs["thermal"]
    L.append(f"Figs. 13-17 use {n['thermal']['force_n']:g} N at "
             f"{n['thermal']['frequency_hz']:g} Hz on the nut (the paper does not state the "
             "excitation of these figures; this is its Fig. 18 condition, below the resonance, "
             "where the response is period-1 and the thermal change of stiffness acts "
             "directly on the amplitude; the amplitude level there depends on the preset: "
             "about 250 um with `paper-tuned`, as in Fig. 18, and 45-51 um with physics.md's "
             "`default`, close to the paper's 37-60 um for Figs. 14-17; the relative changes, "
             "which the claims are about, are similar). At 2000 r/min the thermal chain gives "
             "rises of "
             f"{th['rise_k']['bearing']:.1f} / {th['rise_k']['screw']:.1f} / "
             f"{th['rise_k']['nut']:.1f} K (bearing / screw / nut) and offsets "
             f"D_n = {th['nut_offset_m'] * 1e6:.3f} um, "
             f"D_b = {th['bearing_offset_m'] * 1e6:.3f} um "
             f"against preload deformations of {th['nut_preload_deformation_m'] * 1e6:.2f} um "
             f"(nut) and {th['bearing_preload_deformation_m'] * 1e6:.2f} um (bearing). With "
             "physics.md's sign (heating reduces the contact deformation) the offsets lower "
             "the effective preload and stiffness.\n")
    L.append("| case | amplitude x_n [um] | max abs x_n [um] | rise nut [K] | D_n [um] | "
             "D_b [um] | 1st mode [Hz] |")
    L.append("|---|---|---|---|---|---|---|")
    for name, r in runs.items():
        L.append(f"| {name} | {_um(r['amplitude_m'])} | {_um(r['max_abs_m'])} | "
                 f"{r['rise_k']['nut']:.1f} | {r['nut_offset_m'] * 1e6:.3f} | "
                 f"{r['bearing_offset_m'] * 1e6:.3f} | {r['first_mode_hz']:.0f} |")
    L.append("")
    if "thermal_default_preset" in n:
        d = n["thermal_default_preset"]["runs"]
        L.append("Same cases with physics.md's `default` preset: amplitudes " + ", ".join(
            f"{k} {_um(v['amplitude_m'])} um" for k, v in d.items()) + ".\n")
    L.append("## Motion at the paper's four frequencies (5000 N)\n")
    L.append("Each point carries two labels. The *fixed-transient* label reads the samples "
             "after a fixed number of forcing periods, as the paper's fixed-length "
             "Runge-Kutta runs do (`classify_motion`: stroboscopic repetition, lambda T, "
             "spectrum). The *verified* label (`bsfs_jax.analysis.verify_points`, continuing "
             "the same run) needs evidence: a converged Newton orbit of the period map that "
             "is stable (max |mu| < 1) and that the samples approach (period-n); lambda T "
             "> 0 with a 95 % interval excluding 0 and a broadband spectrum (chaotic); "
             "lambda T ~ 0 within its interval, an unlocked rotation number, one closed "
             "curve and no stable orbit of period <= 16 (quasi-periodic); else "
             "*unresolved*, with the reason. **The verdicts use the verified label only**; "
             "an unresolved point is not checkable.\n")
    L.extend(motion_table_lines(n["motion"], s.transient_periods))
    L.append("")
    if "motion_branches" in n:
        L.append("On the continued sweeps of the same preset (Figs. 24-27 grid), the amplitude "
                 "at the nearest grid frequency is " + "; ".join(
                     f"{b['grid_hz']:.0f} Hz: {_um(b['up_m'])} um (up) / {_um(b['down_m'])} um "
                     "(down)" for b in n["motion_branches"].values())
                 + ". Where up and down differ, the response is multivalued (hysteresis) and a "
                 "cold start from rest picks one branch.\n")
    if "motion_default_preset" in n:
        d = n["motion_default_preset"]
        L.append("With physics.md's `default` preset (verified label, fixed-transient label "
                 "in brackets): " + "; ".join(
                     f"{v['frequency_hz']:g} Hz {v['verified_motion']} [{v['motion']}] "
                     f"{_um(v['amplitude_m'])} um (lambda T {v['lyapunov_per_period']:+.3f})"
                     for v in d.values()) + ".\n")
    L.append("lambda T is the largest Lyapunov exponent per forcing period: for a verified "
             "orbit ln(max |mu|) / n from its Floquet multipliers; for the fixed-transient "
             f"reading, tangent dynamics (Benettin, {s.lyapunov_periods} periods, first "
             "quarter dropped). Negative means a stable periodic attractor, about zero a "
             "torus, clearly positive chaos.\n")
    if "sweep_motions" in n:
        L.append("### Verified motion along the sweeps (Figs. 24-25)\n")
        L.append(f"Continued up and down sweeps, {s.sweep_points} frequencies each way "
                 f"({s.sweep_start_hz:g}-{s.sweep_stop_hz:g} Hz), every point verified "
                 "(`verify_sweep`); the fixed-transient candidates are the classifier's "
                 f"labels of the same samples ({s.sweep_continued_transient} continued "
                 f"transient periods, {s.sweep_periods} recorded). Chaos is judged absent "
                 "only where at most "
                 f"{100 * UNRESOLVED_MAX:.0f} % of the points are unresolved.\n")
        L.append("| Fig. | balls | verified chaotic | verified quasi-periodic | "
                 "verified period-n > 1 | verified period-1 | unresolved (most common "
                 "reasons) | fixed-transient candidates |")
        L.append("|---|---|---|---|---|---|---|---|")
        for key, per in n["sweep_motions"].items():
            for v, sm in per.items():
                pn = "; ".join(f"period-{k} at {_fmt_hz(fs, 4)}" for k, fs in
                               sm["period_n_hz"].items()) or "none"
                unres = f"{sm['unresolved_points']}" + (
                    " (" + "; ".join(f"{c} x {_cell(r)}" for r, c in sm["unresolved_reasons"])
                    + ")"
                    if sm["unresolved_reasons"] else "")
                if sm["failed_points"]:
                    unres += f"; {sm['failed_points']} failed"
                L.append(f"| {key[3:]} | {v:g} | {_fmt_hz(sm['chaotic_hz'])} | "
                         f"{_fmt_hz(sm['quasi_periodic_hz'])} | {pn} | "
                         f"{sm['period_1_points']} of {sm['points']} | {unres} | "
                         f"{describe_candidates(sm)} |")
        L.append("")
    L.append("### Route to chaos\n")
    L.append("The verified search for period-n, quasi-periodic and chaotic motion over "
             "frequency and force (two-parameter atlas) is in "
             "[docs/ROUTE_TO_CHAOS.md](ROUTE_TO_CHAOS.md). Fixed-transient labels differ "
             "from verified ones because the first mode is lightly damped: after a fixed "
             "number of forcing periods (few in time at high frequency) its free vibration "
             "is still in the samples, which then do not repeat and read as period-n, a "
             "torus or chaos although they approach a stable period-1 orbit.\n")
    L.append("## Why the paper's numbers are not matched\n")
    k_chain = n.get("chain_stiffness_n_per_m", float("nan"))
    L.append(
        f"- **Stiffness scale.** Linearised about equilibrium, the nut sees a static chain "
        f"stiffness (bearing pair, screw, nut pair in series) of {k_chain / 1e6:.0f} N/um with "
        f"this preset, so 5000 N deflects it by {5000 / k_chain * 1e6:.0f} um statically. The "
        "paper's 250 um at 500 Hz and 545 um at 636.6 Hz under 5000 N imply a dynamic "
        "stiffness of 9-20 N/um, i.e. a much softer (or more resonant) system than physics.md's "
        "catalogue-based joints; its parameters are not published. The `paper-tuned` preset "
        "changes only [A]-tagged values: the nut mass (the worktable moving with the nut), "
        "chosen so that the 500 Hz amplitude matches Fig. 18, and the three dampers, scaled "
        "by the square root of the mass ratio so that the first mode stays as damped as "
        "with the default masses; the joint stiffnesses stay those of physics.md.")
    lo, hi = runs["speed_1000"], runs["speed_3000"]

    def frac(r, which):  # remaining preload fraction ((delta0 - D) / delta0)^(3/2)
        d0 = r[f"{which}_preload_deformation_m"]
        return max(1.0 - r[f"{which}_offset_m"] / d0, 0.0) ** 1.5

    gamma = float(params.thermal.expansion_per_k)
    need_n = th["nut_preload_deformation_m"] / (gamma * float(params.nut.ball_diameter))
    need_b = th["bearing_preload_deformation_m"] / (gamma * float(params.bearing.ball_diameter))
    L.append(
        f"- **Thermal effect size.** From 1000 to 3000 r/min the nut rise goes from "
        f"{lo['rise_k']['nut']:.1f} to {hi['rise_k']['nut']:.1f} K and the offsets from "
        f"D_n = {lo['nut_offset_m'] * 1e6:.2f} / D_b = {lo['bearing_offset_m'] * 1e6:.2f} um to "
        f"{hi['nut_offset_m'] * 1e6:.2f} / {hi['bearing_offset_m'] * 1e6:.2f} um, against "
        f"preload deformations of {th['nut_preload_deformation_m'] * 1e6:.2f} um (nut) and "
        f"{th['bearing_preload_deformation_m'] * 1e6:.2f} um (bearing): the remaining "
        f"effective preload falls from {100 * frac(lo, 'nut'):.0f} % to "
        f"{100 * frac(hi, 'nut'):.0f} % (nut) and from {100 * frac(lo, 'bearing'):.0f} % to "
        f"{100 * frac(hi, 'bearing'):.0f} % (bearing) of its cold value, and the amplitude "
        f"changes by {100 * (hi['amplitude_m'] / lo['amplitude_m'] - 1):+.1f} %. The paper's "
        "+63 % would need offsets comparable to the preload deformations, i.e. rises of "
        f"about {need_n:.0f} K (nut) or {need_b:.0f} K (bearing), far beyond the 5-20 K it "
        "reports; tuning the [A] conductances that far would not be honest, so they are left "
        "at their defaults.")
    L.append(
        "- **Motion types.** The preloaded double nut and bearing pair never open a gap: "
        "when one half unloads (above 2^(3/2) F_p) the other carries the load, so the "
        "restoring force stays monotonic and the model behaves as a lightly damped hardening "
        "oscillator: period-1 branches, a hard jump at the resonance peak and hysteresis "
        "between up and down sweeps. Period-n, quasi-periodic and chaotic motion of the kind "
        "the paper reports needs much stronger nonlinearity (contact loss with free flight, "
        "or forces far above the unloading force). Exploratory runs made while choosing the "
        "preset (scripts not kept): a 10 kg nut with default and with halved damping, 1000 "
        "transient and 300 Lyapunov periods at 382, 500, 636.6, 680-750 and 1082 Hz, "
        "5000 N: period-1 everywhere, lambda T between -0.025 and +0.013 (computed without "
        "dropping the tangent's alignment transient, so these are upper bounds); a 10 kg "
        "nut with a 400 N bearing preload, continued sweeps "
        "200-1400 Hz: a hardening resonance near 650 Hz with a jump, no consistent chaos.")
    L.append("")
    L.append("## Figures\n")
    for k, p in rep.figures.items():
        L.append(f"- `{Path(p).name}`")
    L.append("")
    L.append("## Run settings and timings\n")
    L.append("```json\n" + json.dumps(dataclasses.asdict(s), indent=1) + "\n```\n")
    for k, v in rep.timings.items():
        L.append(f"- {k}: {v:.1f} s")
    L.append("")
    return "\n".join(L)
