"""The forecast's result: a typed object that also reads as the mapping it replaced."""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping


@dataclasses.dataclass(frozen=True, eq=False)
class Forecast(Mapping):
    """What `forecast` returns.

    - `force_n`: the working force [N]; `band_hz`: [start, stop] of the FRC band [Hz];
    - `quantities`: the forecast quantities (`Quantity`: value, 95 % interval, unit,
      method), modal first, then the FRC's, the first joint's lift-off force, the preloads;
    - `per_joint_liftoff`: each joint's lift-off force (`Quantity`);
    - `health`: {joint: verdict dict with its `line` in words};
    - `curves`: the FRC branches (estimate and probes) for the figure;
      `nominal_branch`: the nominal drive's branch, or None.

    `to_dict()` gives the JSON-ready part (what `prediction.json` holds of it); `fc[key]`
    reads a field by name, as the dict this object replaced did.
    """

    force_n: float
    band_hz: list
    quantities: list
    per_joint_liftoff: list
    health: dict
    curves: object
    nominal_branch: object

    def __getitem__(self, key):
        if key in self._keys():
            return getattr(self, key)
        raise KeyError(key)

    def __iter__(self):
        return iter(self._keys())

    def __len__(self) -> int:
        return len(self._keys())

    @classmethod
    def _keys(cls) -> tuple:
        return tuple(f.name for f in dataclasses.fields(cls))

    def quantity(self, name: str):
        """The quantity called `name` (of `quantities` or `per_joint_liftoff`)."""
        for q in (*self.quantities, *self.per_joint_liftoff):
            if q.name == name:
                return q
        raise KeyError(f"no forecast quantity '{name}'")

    def to_dict(self) -> dict:
        """JSON-ready: force, band, quantities and per-joint lift-off as dicts, health."""
        return dict(force_n=self.force_n, band_hz=list(self.band_hz),
                    quantities=[q.as_dict() for q in self.quantities],
                    per_joint_liftoff=[q.as_dict() for q in self.per_joint_liftoff],
                    health=self.health)
