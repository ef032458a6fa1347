"""Parameters of the ball screw feed system as equinox Modules (SI units throughout).

Every value is a real-valued JAX array, ball counts and angles included, so that any of
them can be differentiated or swept with `vmap`. Only `thermal.enabled` is static (it
changes the computation). Units are converted once, at the TOML boundary (`_io.py`).
"""

import dataclasses
import difflib
import math

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from .._numerics import float_array
from ._vocabulary import BY_NAME, BY_SECTION, PLAUSIBLE, SECTIONS, Key


class ParameterWarning(UserWarning):
    """A legal but implausible parameter value (outside `PLAUSIBLE`): likely a typo or a
    unit slip. The CLI prints it as one line."""


class ParameterError(ValueError):
    """A parameter file or value is malformed or unphysical; the message says which."""


def one_line(text, limit: int = 80) -> str:
    """`text` as it may appear inside a one-line message: control characters (newlines,
    tabs, ...) escaped as in a Python literal, and cut to `limit` characters."""
    text = str(text)
    if not text.isprintable():
        text = "".join(c if c.isprintable() else repr(c)[1:-1] for c in text)
    return text if len(text) <= limit else text[: limit - 3] + "..."


def _arr(x):
    return x if x is None else float_array(x)


class Masses(eqx.Module):
    """Lumped masses [kg]: bearing joint m_b, screw m_s, nut + worktable m_n."""

    bearing: jax.Array = eqx.field(converter=_arr)
    screw: jax.Array = eqx.field(converter=_arr)
    nut: jax.Array = eqx.field(converter=_arr)


class Damping(eqx.Module):
    """Viscous damping [N s/m] of the bearing joint c_b, screw c_s and nut joint c_n."""

    bearing: jax.Array = eqx.field(converter=_arr)
    screw: jax.Array = eqx.field(converter=_arr)
    nut: jax.Array = eqx.field(converter=_arr)


class NutParams(eqx.Module):
    """Preloaded double nut (paper Eqs. 5-16); `balls` per nut half. SI units, radians."""

    balls: jax.Array = eqx.field(converter=_arr)
    ball_diameter: jax.Array = eqx.field(converter=_arr)
    contact_angle: jax.Array = eqx.field(converter=_arr)
    conformity_screw: jax.Array = eqx.field(converter=_arr)
    conformity_nut: jax.Array = eqx.field(converter=_arr)
    pitch_diameter: jax.Array = eqx.field(converter=_arr)
    lead: jax.Array = eqx.field(converter=_arr)
    preload: jax.Array = eqx.field(converter=_arr)
    hertz_k: jax.Array | None = eqx.field(converter=_arr, default=None)


class BearingParams(eqx.Module):
    """Back-to-back angular-contact pair (paper Eqs. 17-28); `balls` per row."""

    balls: jax.Array = eqx.field(converter=_arr)
    ball_diameter: jax.Array = eqx.field(converter=_arr)
    contact_angle: jax.Array = eqx.field(converter=_arr)
    conformity_inner: jax.Array = eqx.field(converter=_arr)
    conformity_outer: jax.Array = eqx.field(converter=_arr)
    pitch_diameter: jax.Array = eqx.field(converter=_arr)
    preload: jax.Array = eqx.field(converter=_arr)
    static_load_rating: jax.Array = eqx.field(converter=_arr)
    hertz_k: jax.Array | None = eqx.field(converter=_arr, default=None)


class ScrewParams(eqx.Module):
    """Screw shaft (Eq. 29) and its material."""

    nominal_diameter: jax.Array = eqx.field(converter=_arr)
    length_to_nut: jax.Array = eqx.field(converter=_arr)
    total_length: jax.Array = eqx.field(converter=_arr)
    youngs_modulus: jax.Array = eqx.field(converter=_arr)
    poisson_ratio: jax.Array = eqx.field(converter=_arr)
    stiffness: jax.Array | None = eqx.field(converter=_arr, default=None)


class ThermalParams(eqx.Module):
    """Speed, ambient and the lumped thermal network (physics.md section 4).

    `nut_offset` / `bearing_offset` [m], when given, replace the thermal model's offsets.
    """

    enabled: bool = eqx.field(static=True)
    speed_rpm: jax.Array = eqx.field(converter=_arr)
    ambient_c: jax.Array = eqx.field(converter=_arr)
    expansion_per_k: jax.Array = eqx.field(converter=_arr)
    oil_viscosity: jax.Array = eqx.field(converter=_arr)
    bearing_f0: jax.Array = eqx.field(converter=_arr)
    nut_heat_factor: jax.Array = eqx.field(converter=_arr)
    g_bearing_screw: jax.Array = eqx.field(converter=_arr)
    g_nut_screw: jax.Array = eqx.field(converter=_arr)
    g_bearing_ambient: jax.Array = eqx.field(converter=_arr)
    g_nut_ambient: jax.Array = eqx.field(converter=_arr)
    natural_convection: jax.Array = eqx.field(converter=_arr)
    nut_offset: jax.Array | None = eqx.field(converter=_arr, default=None)
    bearing_offset: jax.Array | None = eqx.field(converter=_arr, default=None)


_SECTION_CLASSES = {
    "masses": Masses,
    "damping": Damping,
    "nut": NutParams,
    "bearing": BearingParams,
    "screw": ScrewParams,
    "thermal": ThermalParams,
}


class BallScrewParams(eqx.Module):
    """All parameters of the 3-DOF ball screw feed system, in SI units.

    Build one with `load_params(path)`, `preset(name)` or `BallScrewParams.from_dict(d)`
    (a dict in the TOML vocabulary, file units). Change a value with `eqx.tree_at`, or
    with `params.replace("nut.preload_n", 2000.0)` in file units.
    """

    masses: Masses
    damping: Damping
    nut: NutParams
    bearing: BearingParams
    screw: ScrewParams
    thermal: ThermalParams

    # -- construction -------------------------------------------------------------------
    @classmethod
    def from_dict(cls, data: dict, *, source: str = "<dict>") -> "BallScrewParams":
        """Build from a nested dict in the file vocabulary; validates every key and value."""
        check_vocabulary(data, source=source)
        sections = {}
        for section in SECTIONS:
            values = data.get(section, {})
            kwargs = {}
            for key in BY_SECTION[section]:
                if key.key not in values:
                    if key.optional:
                        continue
                    raise ParameterError(
                        f"{source}: missing key '{key.name}' ({key.doc}). Add it, or start from "
                        "`bsfs params` which prints a complete file."
                    )
                kwargs[key.field] = _convert(key, values[key.key], source)
            sections[section] = _SECTION_CLASSES[section](**kwargs)
        params = cls(**sections)
        validate(params, source=source)
        return params

    def to_dict(self) -> dict:
        """Nested dict in the file vocabulary and file units (inverse of `from_dict`)."""
        out: dict = {}
        for section in SECTIONS:
            module = getattr(self, section)
            values = {}
            for key in BY_SECTION[section]:
                v = getattr(module, key.field)
                if v is None:
                    continue
                if key.kind == "bool":
                    values[key.key] = bool(v)
                else:
                    arr = np.asarray(v, dtype=float) / key.to_si
                    values[key.key] = float(arr) if arr.ndim == 0 else arr.tolist()
            out[section] = values
        return out

    def replace(self, name: str, value) -> "BallScrewParams":
        """A copy with `section.key` (file vocabulary and units) set to `value`.

        `value` may be a traced array, so `replace` works inside `jit`/`vmap`/`grad`.
        """
        key = lookup_key(name)
        module = getattr(self, key.section)
        if key.kind == "bool":
            # `enabled` is static, so tree_at cannot reach it; rebuild the module instead.
            new = dataclasses.replace(module, enabled=bool(value))
        else:
            si = jnp.asarray(value, dtype=float) * key.to_si
            new = eqx.tree_at(lambda m: getattr(m, key.field), module, si,
                              is_leaf=lambda x: x is None)
        return eqx.tree_at(lambda p: getattr(p, key.section), self, new)

    def get(self, name: str):
        """Value of `section.key` in file units (None for an absent optional key)."""
        key = lookup_key(name)
        v = getattr(getattr(self, key.section), key.field)
        if v is None or key.kind == "bool":
            return v
        return v / key.to_si


def lookup_key(name: str) -> Key:
    """The vocabulary entry for `section.key`, or a ParameterError with suggestions."""
    if name in BY_NAME:
        return BY_NAME[name]
    close = difflib.get_close_matches(str(name), list(BY_NAME), n=3, cutoff=0.5)
    hint = f" Did you mean {', '.join(repr(c) for c in close)}?" if close else ""
    raise ParameterError(f"unknown parameter '{one_line(name)}'.{hint} Run `bsfs params` for "
                         "the list.")


def check_vocabulary(data: dict, *, source: str = "<dict>") -> None:
    """Reject unknown sections and keys, with a 'did you mean' suggestion."""
    if not isinstance(data, dict):
        raise ParameterError(f"{source}: expected a table of sections, got {type(data).__name__}")
    for section, values in data.items():
        if section not in SECTIONS:
            close = difflib.get_close_matches(section, SECTIONS, n=1, cutoff=0.5)
            hint = f" Did you mean [{close[0]}]?" if close else ""
            raise ParameterError(
                f"{source}: unknown section [{one_line(section)}].{hint} Allowed: "
                + ", ".join(f"[{s}]" for s in SECTIONS)
            )
        if not isinstance(values, dict):
            raise ParameterError(f"{source}: [{section}] must be a table of key = value lines")
        known = [k.key for k in BY_SECTION[section]]
        for key in values:
            if key not in known:
                close = difflib.get_close_matches(key, known, n=1, cutoff=0.5)
                hint = f" Did you mean '{close[0]}'?" if close else ""
                raise ParameterError(
                    f"{source}: unknown key '{one_line(key)}' in [{section}].{hint} "
                    f"Allowed keys in [{section}]: {', '.join(known)}."
                )


def check_value(name: str, value, source: str = "parameters"):
    """`value` (file units) for the vocabulary key `name`, checked as a file's value is:
    a number within the allowed range (or true/false for a switch); returns it in SI
    units. ParameterError naming the key otherwise."""
    return _convert(lookup_key(name), value, source)


def _convert(key: Key, value, source: str):
    if key.kind == "bool":
        if not isinstance(value, bool):
            raise ParameterError(f"{source}: '{key.name}' must be true or false, got "
                                 f"{one_line(repr(value), 40)}")
        return value
    if isinstance(value, bool) or not isinstance(value, int | float):
        raise ParameterError(
            f"{source}: '{key.name}' must be a number, got {one_line(repr(value), 40)} "
            f"({type(value).__name__})"
        )
    try:
        number = float(value)
    except OverflowError:  # an integer beyond 1.8e308
        raise ParameterError(f"{source}: '{key.name}' = {one_line(value, 20)} is too large "
                             f"for a number; allowed {key.range_text()} ({key.doc})") from None
    _check_range(key, number, source)
    if not math.isfinite(number * key.to_si):
        raise ParameterError(f"{source}: '{key.name}' = {number:g} overflows in SI units; "
                             f"allowed {key.range_text()} ({key.doc})")
    return number * key.to_si


def _check_range(key: Key, value: float, source: str) -> None:
    if not math.isfinite(value):
        raise ParameterError(f"{source}: '{key.name}' = {value} is not finite")
    bad = False
    if key.low is not None:
        bad |= value <= key.low if key.low_open else value < key.low
    if key.high is not None:
        bad |= value >= key.high if key.high_open else value > key.high
    if bad:
        raise ParameterError(
            f"{source}: '{key.name}' = {value:g} is outside the allowed range {key.range_text()}"
            f" ({key.doc})."
        )


def _is_concrete(x) -> bool:
    return not isinstance(x, jax.core.Tracer)


def _check_plausible(key: Key, arr, source: str) -> None:
    span = PLAUSIBLE.get(key.name)
    if span is None:
        return
    lo, hi = span
    bad = [float(x) for x in np.atleast_1d(arr).ravel() if not lo <= float(x) <= hi]
    if bad:
        import warnings

        warnings.warn(ParameterWarning(
            f"{source}: '{key.name}' = {bad[0]:g} is outside the plausible range "
            f"[{lo:g}, {hi:g}] of a machine-tool ball screw drive; check the value and its "
            "unit (the results may be meaningless)"), stacklevel=3)


def validate(params: BallScrewParams, *, source: str = "parameters") -> BallScrewParams:
    """Check every concrete value against its allowed range and the cross-key rules.

    Traced values (inside `jit`/`grad`) are skipped: validate before transforming.
    Raises `ParameterError` naming the key, the value and the allowed range; warns with
    a `ParameterWarning` for a legal value outside the plausible range (`PLAUSIBLE`).
    """
    for section in SECTIONS:
        module = getattr(params, section)
        for key in BY_SECTION[section]:
            v = getattr(module, key.field)
            if v is None or key.kind == "bool" or not _is_concrete(v):
                continue
            arr = np.asarray(v, dtype=float) / key.to_si
            for item in np.atleast_1d(arr).ravel():
                _check_range(key, float(item), source)
            _check_plausible(key, arr, source)
    n, b, s = params.nut, params.bearing, params.screw
    leaves = [n.pitch_diameter, n.ball_diameter, b.pitch_diameter, b.ball_diameter,
              s.nominal_diameter, n.contact_angle]
    if all(_is_concrete(x) for x in leaves):
        if np.any(np.asarray(n.pitch_diameter) <= np.asarray(n.ball_diameter)):
            raise ParameterError(f"{source}: 'nut.pitch_diameter_mm' must exceed "
                                 "'nut.ball_diameter_mm'")
        if np.any(np.asarray(b.pitch_diameter) <= np.asarray(b.ball_diameter)):
            raise ParameterError(f"{source}: 'bearing.pitch_diameter_mm' must exceed "
                                 "'bearing.ball_diameter_mm'")
        root = np.asarray(s.nominal_diameter) - np.asarray(n.ball_diameter) * np.cos(
            np.asarray(n.contact_angle))
        if np.any(root <= 0):
            raise ParameterError(
                f"{source}: screw root diameter 'screw.nominal_diameter_mm' - "
                f"d_b cos(beta) = {float(np.min(root)) * 1e3:g} mm must be positive"
            )
    return params
