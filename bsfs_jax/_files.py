"""One home for what every layer writes: atomic files, JSON encoding, chunk checkpoints."""

import dataclasses
import json
import os
import tempfile
from collections.abc import Callable
from pathlib import Path

import numpy as np


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


def write_atomic(path, write: Callable[[Path], object]) -> Path:
    """Create `path` atomically: `write(tmp)` fills a temporary file in the same folder,
    which is then renamed onto `path`.

    A reader never sees a half-written file, and an interrupted write leaves the old
    file intact. The result gets the usual permissions (0666 less the umask).
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    os.close(fd)
    try:
        write(Path(tmp))
        os.chmod(tmp, 0o666 & ~_umask())
        os.replace(tmp, path)
    except BaseException:
        if os.path.exists(tmp):
            os.unlink(tmp)
        raise
    return path


def write_bytes_atomic(path, payload: bytes) -> Path:
    """Write `payload` to `path` atomically (see `write_atomic`)."""
    return write_atomic(path, lambda tmp: tmp.write_bytes(payload))


def write_text_atomic(path, text: str) -> Path:
    return write_bytes_atomic(path, text.encode())


def save_figure(fig, path, *, tight: bool = True, dpi: int = 130) -> Path:
    """Save a matplotlib figure atomically (format from the suffix, PNG by default).
    `tight`: crop to the drawn artists (a second drawing pass); False for figures laid out
    by `tight_layout`."""
    import io

    buf = io.BytesIO()
    fig.savefig(buf, format=Path(path).suffix.lstrip(".") or "png", dpi=dpi,
                bbox_inches="tight" if tight else None)
    return write_bytes_atomic(path, buf.getvalue())


def save_npz_atomic(path, **arrays) -> Path:
    """`np.savez(path, **arrays)` atomically (the name is kept as given)."""

    def write(tmp: Path):
        with open(tmp, "wb") as fh:
            np.savez(fh, **arrays)

    return write_atomic(path, write)


def save_netcdf_atomic(path, dataset) -> Path:
    """Write an `xarray.Dataset` as NetCDF4 (engine h5netcdf), atomically."""
    return write_atomic(path, lambda tmp: dataset.to_netcdf(tmp, engine="h5netcdf"))


def open_netcdf(path, what: str, fmt: str):
    """Load a NetCDF4 file written by `save_netcdf_atomic` whose `format` attribute is
    `fmt`; one-line FileNotFoundError / ValueError naming the file and `what` it should
    be otherwise."""
    import xarray as xr

    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"{path}: no such {what} file")
    try:
        with xr.open_dataset(path, engine="h5netcdf", decode_times=False,
                             decode_timedelta=False) as ds:
            ds = ds.load()
    except Exception as exc:  # not HDF5 / NetCDF4 at all
        raise ValueError(f"{path}: not a bsfs {what} file (not readable as NetCDF4: "
                         f"{type(exc).__name__})") from None
    if ds.attrs.get("format") != fmt:
        raise ValueError(f"{path}: not a bsfs {what} file (format "
                         f"{ds.attrs.get('format')!r}, expected {fmt!r})")
    return ds


def jsonable(obj, *, omit: Callable[[object], bool] | None = None):
    """`obj` with every part made JSON-encodable.

    Dicts (keys become strings), lists, tuples and sets, dataclass instances (as dicts),
    numpy/JAX arrays (nested lists) and numpy scalars (Python numbers) are converted
    recursively; non-finite floats become None (JSON has no NaN). Objects for which
    `omit(obj)` is true become None; anything else is returned unchanged.
    """
    if omit is not None and omit(obj):
        return None
    if isinstance(obj, dict):
        return {str(k): jsonable(v, omit=omit) for k, v in obj.items()}
    if isinstance(obj, list | tuple | set | frozenset):
        return [jsonable(v, omit=omit) for v in obj]
    if dataclasses.is_dataclass(obj) and not isinstance(obj, type):
        return jsonable(dataclasses.asdict(obj), omit=omit)
    if isinstance(obj, np.generic) or hasattr(obj, "shape") and hasattr(obj, "dtype"):
        arr = np.asarray(obj)
        return jsonable(arr.item() if arr.ndim == 0 else arr.tolist(), omit=omit)
    if isinstance(obj, float) and not np.isfinite(obj):
        return None
    return obj


def _is_writer() -> bool:
    """Only process 0 writes shared files (multi-process JAX); True without JAX loaded."""
    import sys

    jax = sys.modules.get("jax")
    return jax is None or jax.process_index() == 0


class ChunkCheckpoint:
    """A folder of per-chunk .npz files plus a manifest naming the run they belong to.

    - The manifest (`manifest.json`, written atomically) holds `fingerprint`: a folder
      written for another fingerprint raises a ValueError instead of being mixed in.
    - `load(k)` returns chunk k's arrays, or None when it is missing or damaged (so it is
      recomputed); `save(k, arrays)` writes it atomically.
    - Only process 0 writes (under `jax.distributed`, every process reads).
    - `folder=None`: no checkpointing (load returns None, save does nothing).
    """

    MANIFEST = "manifest.json"

    def __init__(self, folder, fingerprint: str, n_chunks: int, *, prefix: str = "chunk"):
        self.folder = None if folder is None else Path(folder)
        self.fingerprint = fingerprint
        self.prefix = prefix
        if self.folder is None:
            return
        manifest = self.folder / self.MANIFEST
        if manifest.exists():
            old = json.loads(manifest.read_text())
            if old.get("fingerprint") != fingerprint:
                raise ValueError(
                    f"checkpoint folder '{self.folder}' holds a different sweep (fingerprint "
                    f"{old.get('fingerprint')} != {fingerprint}: other values, parameters or "
                    "settings). Use a new folder, or delete this one to start over.")
        elif _is_writer():
            write_text_atomic(manifest, json.dumps({"fingerprint": fingerprint,
                                                    "n_chunks": int(n_chunks)}))

    def path(self, k: int) -> Path:
        return self.folder / f"{self.prefix}_{k:05d}.npz"

    def load(self, k: int) -> dict | None:
        if self.folder is None or not self.path(k).exists():
            return None
        try:
            with np.load(self.path(k), allow_pickle=False) as z:
                return {name: z[name] for name in z.files}
        except (OSError, ValueError, EOFError):
            return None  # a damaged file is recomputed

    def save(self, k: int, arrays: dict) -> None:
        if self.folder is not None and _is_writer():
            save_npz_atomic(self.path(k), **arrays)
