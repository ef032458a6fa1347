"""TOML reading and writing of parameter files, and the bundled presets."""

import tomllib
from importlib import resources
from pathlib import Path

import numpy as np
import tomli_w

from .._files import write_text_atomic
from ._params import BallScrewParams, ParameterError, one_line
from ._vocabulary import BY_SECTION, SECTIONS

PRESET_PACKAGE = "bsfs_jax.params.presets"


def load_params(path, *, overrides: dict | None = None) -> BallScrewParams:
    """Read a TOML parameter file (physics.md section 2 vocabulary).

    A file may hold only some keys and name a `base = "preset-name"` at the top; the rest
    then comes from that preset (default: "default"). `overrides` is a nested dict in the
    same vocabulary applied last. Errors name the file and the key.
    """
    path = Path(path)
    shown = one_line(str(path), 500)  # every message is one line, whatever the file is called
    try:
        text = path.read_text(encoding="utf-8")
    except UnicodeDecodeError:
        raise ParameterError(f"{shown}: not a text (UTF-8) file; a parameter file is TOML "
                             "text (`bsfs params > file.toml` writes a complete one)") from None
    except OSError as exc:
        raise ParameterError(f"cannot read parameter file '{shown}': {exc.strerror}") from None
    try:
        data = tomllib.loads(text)
    except ValueError as exc:  # TOMLDecodeError, or an integer of more than 4300 digits
        raise ParameterError(f"{shown}: not valid TOML: {one_line(str(exc))}") from None
    except RecursionError:  # arrays or inline tables nested thousands deep
        raise ParameterError(f"{shown}: not valid TOML: arrays or tables nested too deeply"
                             ) from None
    if not data:
        raise ParameterError(f"{shown}: the file sets no parameters (empty); write the keys to "
                             "change, or name a preset with --preset (`bsfs params --list`)")
    return _from_partial(data, source=shown, overrides=overrides)


def _from_partial(data: dict, *, source: str, overrides: dict | None = None):
    base_name = data.pop("base", None)
    if base_name is not None and not isinstance(base_name, str):
        raise ParameterError(f"{source}: 'base' must be a preset name string")
    try:
        base = _preset_dict(base_name or "default")
    except ParameterError as exc:
        raise ParameterError(f"{source}: 'base': {exc}") from None
    merged = _merge(base, data)
    if overrides:
        merged = _merge(merged, overrides)
    return BallScrewParams.from_dict(merged, source=source)


def _merge(base: dict, extra: dict) -> dict:
    out = {k: dict(v) if isinstance(v, dict) else v for k, v in base.items()}
    for k, v in extra.items():
        if isinstance(v, dict) and isinstance(out.get(k), dict):
            out[k].update(v)
        else:
            out[k] = v
    return out


def list_presets() -> list[str]:
    """Names of the bundled presets."""
    files = resources.files(PRESET_PACKAGE).iterdir()
    return sorted(f.name[:-5] for f in files if f.name.endswith(".toml"))


def _preset_dict(name: str) -> dict:
    names = list_presets()
    if name not in names:
        import difflib

        close = difflib.get_close_matches(name, names, n=1)
        hint = f" Did you mean '{close[0]}'?" if close else ""
        raise ParameterError(f"unknown preset '{one_line(name)}'.{hint} Available: "
                             f"{', '.join(names)}")
    data = tomllib.loads(resources.files(PRESET_PACKAGE).joinpath(f"{name}.toml").read_text())
    base = data.pop("base", None)
    data.pop("description", None)
    return _merge(_preset_dict(base), data) if base else data


def preset(name: str = "default") -> BallScrewParams:
    """A bundled parameter set: "default" (physics.md section 2) or a named variant."""
    return BallScrewParams.from_dict(_preset_dict(name), source=f"preset '{name}'")


def preset_description(name: str) -> str:
    data = tomllib.loads(resources.files(PRESET_PACKAGE).joinpath(f"{name}.toml").read_text())
    return data.get("description", "")


def params_to_toml(params: BallScrewParams, *, header: str = "") -> str:
    """A complete, commented TOML parameter file for `params` (file units)."""
    data = params.to_dict()
    lines = []
    if header:
        lines += [f"# {line}" for line in header.splitlines()] + [""]
    for section in SECTIONS:
        lines.append(f"[{section}]")
        for key in BY_SECTION[section]:
            if key.key not in data[section]:
                lines.append(f"# {key.key} = ...  # optional: {key.doc}")
                continue
            value = tomli_w.dumps({"v": data[section][key.key]}).strip()[4:]
            lines.append(f"{key.key} = {value}  # {key.doc}; allowed {key.range_text()}"
                         if key.kind != "bool" else f"{key.key} = {value}  # {key.doc}")
        lines.append("")
    text = "\n".join(lines)
    tomllib.loads(text)  # self-check: what we write must read back
    return text


def save_params(params: BallScrewParams, path, *, header: str = "", overwrite: bool = False):
    """Write `params` as TOML atomically (temp file + rename). Refuses to overwrite unless asked."""
    path = Path(path)
    if path.exists() and not overwrite:
        raise FileExistsError(f"'{path}' exists; pass overwrite=True or choose another name")
    write_text_atomic(path, params_to_toml(params, header=header))
    return path


def params_summary(params: BallScrewParams) -> dict:
    """Flat {section.key: value} in file units, for reports."""
    out = {}
    for section, values in params.to_dict().items():
        for k, v in values.items():
            out[f"{section}.{k}"] = v if not isinstance(v, float | np.floating) else float(v)
    return out
