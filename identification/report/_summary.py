"""The identification's text summary (every number once, each with what it rests on) and
its parameter rows (report.json's `parameters`)."""

from __future__ import annotations

import numpy as np

from ..intervals import IDENTIFIABLE_STD
from ..measurement import is_frf


def _record_line(data) -> str:
    parts = []
    for d in data[:6]:
        if is_frf(d):
            f = np.asarray(d.frequency_hz)
            parts.append(f"{d.excitation} FRF {f.min():.4g}-{f.max():.4g} Hz/{d.speed_rpm:g} rpm")
        else:
            parts.append(f"{d.frequency_hz:.4g} Hz/{d.record.force_amplitude_n:g} N/"
                         f"{d.speed_rpm:g} rpm")
    return ", ".join(parts) + (" ..." if len(data) > 6 else "")


def _fmt_ci(lo, hi) -> str:
    if not (np.isfinite(lo) and np.isfinite(hi)):
        return "not determined"
    return f"[{lo:.4g}, {hi:.4g}]"


def parameter_rows(res) -> dict:
    """report.json's `parameters`: value, std, ci95, identified and what they rest on."""
    pb, u = res.problem, res.uncertainty
    out = {}
    for i, name in enumerate(pb.names):
        lo, hi = u.ci95[i]
        finite = bool(np.isfinite(lo) and np.isfinite(hi))
        prior = float(pb.prior_values[i])
        change = (float(u.values[i] / prior - 1.0) if pb.is_log[i]
                  else float(u.values[i] - prior))
        out[name] = dict(
            key=pb.keys[i], speed_rpm=pb.param_speeds[i], unit=pb.units[i],
            value=float(u.values[i]),
            std=float(u.std[i]) if np.isfinite(u.std[i]) else None,
            ci95=[float(lo), float(hi)] if finite else None,
            ci_method=u.ci_method[i],
            relative_std=float(u.scaled_std[i]) if pb.is_log[i] and np.isfinite(
                u.scaled_std[i]) else None,
            identified=bool(u.determined[i]), status=u.status(i),
            prior=prior,
            prior_sigma=None if u.prior_sigma is None else float(u.prior_sigma[i]),
            data_share=None if u.data_share is None else float(u.data_share[i]),
            change_from_prior=change,
            differs_from_prior=bool(u.determined[i] and finite and not lo <= prior <= hi),
        )
    return out


def preload_verdicts(res) -> list[str]:
    """One line per fitted preload: the change from nominal and whether it is significant."""
    lines = []
    for name, row in parameter_rows(res).items():
        if not name.endswith("_preload"):
            continue
        joint = name.split("_")[0]
        change = 100.0 * row["change_from_prior"]
        if not row["identified"]:
            lines.append(f"{joint} preload: not determined by these records, so a loss cannot "
                         "be judged (run `bsfs plan-test --fit nut_preload,bearing_preload`)")
            continue
        lo, hi = row["ci95"]
        if row["differs_from_prior"]:
            word = "LOSS" if change < 0 else "INCREASE"
            lines.append(f"{joint} preload: {row['value']:.0f} N vs nominal {row['prior']:.0f} "
                         f"N ({change:+.0f} %, 95 % interval {lo:.0f}-{hi:.0f} N): significant "
                         f"{word} (the nominal value is outside the interval)")
        else:
            lines.append(f"{joint} preload: {row['value']:.0f} N vs nominal {row['prior']:.0f} "
                         f"N ({change:+.0f} %, 95 % interval {lo:.0f}-{hi:.0f} N): no "
                         "significant change")
    return lines


_CHOICE = {"confirmed": "; models per record confirmed at the estimate",
           "refitted": "; models per record re-chosen at the estimate and the fit repeated"}


def _left_out_lines(res) -> list[str]:
    """One line per chirp whose lines near a resonance drive the joints beyond linear."""
    out = []
    for i, mask in sorted(res.problem.frf_left_out.items()):
        d = res.data[i]
        f = np.asarray(d.frequency_hz)[mask]
        z = float(np.max(res.problem.linearisation_z[i]))
        out.append(f"Record '{d.name}': {mask.sum()} of {mask.size} lines ({f.min():.0f}-"
                   f"{f.max():.0f} Hz) left out: at {d.force_amplitude_n:g} N the joints are "
                   f"not linear there (linear-model error up to {z:.2g} standard errors). "
                   "A lower chirp level keeps them.")
    return out


def _stage_lines(fr) -> list[str]:
    st = fr.stage1
    if not st:
        return []
    est = st.get("first_estimate") or {}
    if est.get("estimate"):
        first = (f"First estimate: {est['summary']}. Every start was moved onto it through "
                 "the model's linearisation (closest point in the prior's metric).")
        where = " on that resonance"
    else:
        first = (f"No first estimate from the records ({est['why_not']}); the starts are "
                 "spread over the prior alone." if est.get("why_not") else None)
        where = ""
    if st["stage"] is None:
        return ([first] if first else []) + [
            f"No first stage (every record is on the periodic-orbit model): the full fit "
            f"started from {st['starts']} quasi-random starts over the prior's 95 % "
            f"region{where}."]
    return ([first] if first else []) + [
            f"Staged fit: first {st['records']} record(s) ({st['stage']}) from "
            f"{st['starts']} quasi-random starts over the prior's 95 % region{where}: "
            f"{st['reached_best']} reached the best cost ({st['distinct_optima']} distinct "
            f"optim{'um' if st['distinct_optima'] == 1 else 'a'}); the full fit started from "
            + ("it." if st.get("full_fit_starts", 1) == 1 else
               f"the {st['full_fit_starts']} lowest.")] + _rescue_lines(st)


def _rescue_lines(st) -> list[str]:
    r = st.get("rescue")
    if not r:
        return []
    costs = ", ".join(f"{c:.6g}" for c in r["costs"])
    return [f"Its estimate left {', '.join(r['records'])} outside their noise (cost "
            f"{r['cost_before']:.6g}), so the full fit ran again from {r['starts']} starts "
            "(that estimate, and the first stage's optimum moved two of its standard "
            "deviations either way along its two least determined directions): costs "
            f"{costs}; " + ("the lowest is the estimate." if r["taken"] else
                            "none lower, the estimate stands.")]


def _branch_lines(res) -> list[str]:
    """Which orbit each periodic-orbit record was fitted on (one line), and a line per
    record whose orbit is unresolved or whose model truncation error is not small."""
    from ..measurement import MODEL_ERROR

    br = getattr(res, "branches", None) or {}
    if not br:
        return []
    names = {i: res.data[i].name for i in br}
    text = ", ".join(f"'{names[i]}' {b['branch']}" for i, b in sorted(br.items()))
    out = [f"Branches (periodic-orbit records; up- and down-sweep orbits at the estimate): "
           f"{text}."]
    h = res.problem.structure.orbit_harmonics
    for i, b in sorted(br.items()):
        if b["branch"] == "unresolved":
            out.append(f"Record '{names[i]}': its fitted orbit is not one that a stepped sine "
                       "reaches sweeping up or down (or it is unstable, or an orbit failed); "
                       "check the record and the fit's branch.")
        if not b["orbit_truncation_error_std"] <= MODEL_ERROR:
            out.append(f"Record '{names[i]}': the orbit model's truncation error is "
                       f"{b['orbit_truncation_error_std']:.2g} standard errors (above "
                       f"{MODEL_ERROR:g}; {h} against {2 * h} harmonics).")
    return out


def summary_text(res) -> str:
    pb, fr, u = res.problem, res.fit, res.uncertainty
    synth = any(str((d.meta if is_frf(d) else d.record.meta).get("synthetic", "")).lower()
                == "true" for d in res.data)
    kinds = {k: sum(m == k for m in pb.models)
             for k in ("linear", "first-order", "nonlinear", "frf")}
    lines = [f"Identification from {len(res.data)} record(s)"
             f"{' (SYNTHETIC data)' if synth else ''}: {_record_line(res.data)}",
             f"Model: linearised FRF for {kinds['linear']} sine record(s), first-order "
             f"nonlinear correction for {kinds['first-order']}, periodic orbit (harmonic "
             f"balance) for {kinds['nonlinear']}, {kinds['frf']} FRF record(s); "
             + ("maximum a posteriori with priors (sigma in the table)" if pb.priors is not None
                else "maximum likelihood (no priors)") + f"; {res.seconds:.1f} s.",
             *_left_out_lines(res),
             *_stage_lines(fr),
             *_branch_lines(res),
             f"Fit {fr.convergence_text}; {fr.steps} iterations" + _CHOICE.get(fr.model_choice,
                                                                               "") + ".",
             f"Noise: {u.noise['text']}.", ""]
    head = f"{'parameter':<18}{'value':>11}{'std':>10}   {'95% interval':<24}{'unit':<11}"
    head += "prior (sigma)       " if pb.priors is not None else ""
    lines.append(head + "status")
    for i, name in enumerate(pb.names):
        lo, hi = u.ci95[i]
        std = f"{u.std[i]:.3g}" if np.isfinite(u.std[i]) else "-"
        ci = _fmt_ci(lo, hi) + ("*" if u.ci_method[i] == "profile" else "")
        row = f"{name:<18}{u.values[i]:>11.4g}{std:>10}   {ci:<24}{pb.units[i]:<11}"
        if pb.priors is not None:
            sig = (f"x/{np.exp(u.prior_sigma[i]):.2g}" if pb.is_log[i]
                   else f"+-{u.prior_sigma[i]:.2g}")
            row += f"{pb.prior_values[i]:.4g} ({sig})".ljust(20)
        status = u.status(i)
        row += status.upper() if status != "determined by the data" else status
        lines.append(row)
    if "profile" in u.ci_method:
        lines.append("* profile-likelihood interval (the linearised one was doubtful)")
    if str(u.noise.get("profile", "")).startswith("skipped"):
        lines.append(f"Intervals are linearised; the profile-likelihood check was "
                     f"{u.noise['profile']}.")
    lines.append("")
    for speed, c in u.compliance.items():
        ok = c["relative_std"] < IDENTIFIABLE_STD
        lines.append(f"Series (static) compliance at {speed} rpm: {c['compliance_nm_per_n']:.5g}"
                     f" +- {c['std_nm_per_n']:.2g} nm/N ({100 * c['relative_std']:.2g} %), "
                     f"i.e. stiffness {c['stiffness_n_per_um']:.4g} N/um"
                     + (" - determined by the data" if ok else " - not determined"))
    ident = u.identifiable()
    lines.append(f"Combinations the records alone determine ({sum(ident)} of {len(ident)}; "
                 f"standard error < {IDENTIFIABLE_STD:g} in log-value or um):")
    for i in np.nonzero(ident)[0]:
        lines.append(f"  [{u.direction_std[i]:.2g}] {u.combination_text(i)}")
    lines += preload_verdicts(res)
    n_det = int(np.sum(u.determined))
    if n_det == 0:
        comp = [c for c in u.compliance.values() if c["relative_std"] < IDENTIFIABLE_STD]
        what = (f"the {sum(ident)} combination(s) listed above (the series compliance "
                "among them)" if comp else f"the {sum(ident)} combination(s) listed above")
        lines.append(f"=> No single parameter is determined by these records: they determine "
                     f"{what}, so every fitted parameter is "
                     + ("prior-dominated (its value is the prior's, moved only as far as those "
                        "combinations need)" if pb.priors is not None else "undetermined")
                     + ". Run `bsfs plan-test` for a test that separates them.")
    elif n_det < pb.n_params:
        rest = [n for i, n in enumerate(pb.names) if not u.determined[i]]
        lines.append(f"=> {n_det} of {pb.n_params} parameters determined by the data; "
                     f"{', '.join(rest)} rest on the prior.")
    else:
        lines.append(f"=> All {pb.n_params} parameters are determined by the data.")
    if not fr.converged:
        lines.append("=> WARNING: the fit did not converge; treat every value above as "
                     "provisional (raise --max-steps or --starts).")
    return "\n".join(lines)
