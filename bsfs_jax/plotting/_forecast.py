"""`bsfs predict`'s figure: the FRC at the working force with its band, the folds and the
peak with their 95 % intervals, and the nominal drive beside it."""

import numpy as np


def forecast_figure(curves: dict, nominal, quantities: dict, force_n: float):
    """`curves`: {"estimate": Branch, "probe<i><+|->": Branch at each second-order probe};
    `nominal`: the nominal drive's Branch or None; `quantities`: {name: dict with value,
    ci95}. Returns the matplotlib figure."""
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(8.0, 5.6))
    ends = [b for k, b in curves.items() if k != "estimate"]
    for i, b in enumerate(ends):
        ax.plot(b.p, b.amplitude * 1e6, color="tab:blue", alpha=0.25, lw=0.8,
                label="FRCs at the probes (1.96 std along the least determined directions)"
                if i == 0 else None)
    est = curves["estimate"]
    stable = np.where(est.stable, est.amplitude * 1e6, np.nan)
    unstable = np.where(~est.stable, est.amplitude * 1e6, np.nan)
    ax.plot(est.p, stable, color="tab:blue", lw=1.8, label="identified drive (stable)")
    ax.plot(est.p, unstable, color="tab:blue", lw=1.2, ls="--", label="unstable")
    if nominal is not None:
        ax.plot(nominal.p, nominal.amplitude * 1e6, color="0.4", lw=1.2,
                label="nominal drive")
    pf, pa = quantities["peak_frequency_hz"], quantities["peak_amplitude_um"]
    if pf["value"] is not None and pa["value"] is not None:
        xerr = _err(pf)
        yerr = _err(pa)
        ax.errorbar([pf["value"]], [pa["value"]], xerr=xerr, yerr=yerr, fmt="o",
                    color="tab:red", capsize=3, label="peak, 95 % intervals")
    for name, marker in (("fold_up_hz", "^"), ("fold_down_hz", "v")):
        q = quantities[name]
        if q["value"] is None:
            continue
        amp = q.get("amplitude_um")  # the fold's own amplitude (the curve is folded there)
        if amp is None:
            amp = np.interp(q["value"], est.p[np.argsort(est.p)],
                            (est.amplitude * 1e6)[np.argsort(est.p)])
        ax.errorbar([q["value"]], [amp], xerr=_err(q), fmt=marker, color="tab:orange",
                    capsize=3, label=f"{name.split('_')[1]}-sweep jump (fold), 95 % interval")
    ax.set_xlabel("excitation frequency [Hz]")
    ax.set_ylabel("nut amplitude, half peak-to-peak [um]")
    ax.set_title(f"Forecast at {force_n:g} N: frequency response near the first resonance")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8, loc="upper center", bbox_to_anchor=(0.5, -0.14), ncol=2)
    return fig


def _err(q):
    v, ci = q["value"], q["ci95"]
    if ci is None:
        return None
    lo = 0.0 if ci[0] is None else v - ci[0]
    hi = 0.0 if ci[1] is None else ci[1] - v
    return [[max(lo, 0.0)], [max(hi, 0.0)]]
