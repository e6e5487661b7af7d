"""Vehicle parameters, as f1tenth_gym users pass them and as ``paddock sysid`` writes them.

``params``: a dict with f1tenth_gym's keys (:data:`VEHICLE_KEYS`); the keys given replace
the defaults (:data:`DEFAULT_PARAMS`, f1tenth_gym's own), the others keep theirs.
``vehicle``: the path of a vehicle YAML (the ``vehicle.yaml`` that ``paddock sysid``
writes: these keys plus ``model``, ``integrator`` and the fitted ``effects:``). Given
both, ``params`` apply on top of the file.

The parameters travel to the worker as vehicle YAML inside the request, so every worker
simulates the same car: the worker parses and checks it (an out-of-range value comes
back as :class:`paddock.errors.InvalidArgument` naming the key and the value).
"""

from __future__ import annotations

import math
import os
from collections.abc import Mapping

#: f1tenth_gym's vehicle parameter keys.
VEHICLE_KEYS = ("mu", "C_Sf", "C_Sr", "lf", "lr", "h", "m", "I", "s_min", "s_max", "sv_min",
                "sv_max", "v_switch", "a_max", "v_min", "v_max", "width", "length")

#: f1tenth_gym's default vehicle (the simulator's defaults too).
DEFAULT_PARAMS = {"mu": 1.0489, "C_Sf": 4.718, "C_Sr": 5.4562, "lf": 0.15875, "lr": 0.17145,
                  "h": 0.074, "m": 3.74, "I": 0.04712, "s_min": -0.4189, "s_max": 0.4189,
                  "sv_min": -3.2, "sv_max": 3.2, "v_switch": 7.319, "a_max": 9.51,
                  "v_min": -5.0, "v_max": 20.0, "width": 0.31, "length": 0.58}


def params_yaml(params: Mapping[str, float]) -> str:
    """``params`` as a vehicle YAML document; unknown keys and values that are not finite
    numbers raise :class:`ValueError` naming the key and the value."""
    lines = []
    for key, value in params.items():
        if key not in VEHICLE_KEYS:
            raise ValueError(f"params: unknown vehicle parameter {key!r} = {value!r} "
                             f"(f1tenth_gym's keys: {', '.join(VEHICLE_KEYS)})")
        if isinstance(value, bool):
            raise ValueError(f"params[{key!r}] = {value!r} is not a number")
        try:
            x = float(value)
        except (TypeError, ValueError):
            raise ValueError(f"params[{key!r}] = {value!r} is not a number") from None
        if not math.isfinite(x):
            raise ValueError(f"params[{key!r}] = {value!r} is not a finite number")
        # repr: the shortest text that reads back as the same double, so the worker
        # simulates exactly these values
        lines.append(f"{key}: {x!r}\n")
    return "".join(lines)


def vehicle_yaml(params: Mapping[str, float] | None = None,
                 vehicle: str | os.PathLike[str] | None = None) -> str:
    """The vehicle YAML of a request: the file's text, then ``params`` as a later YAML
    document (later documents' keys win). Empty: the default vehicle."""
    docs = []
    if vehicle is not None:
        path = os.fspath(vehicle)
        try:
            with open(path, encoding="utf-8") as f:
                docs.append(f.read())
        except OSError as e:
            raise ValueError(f"vehicle: cannot read the vehicle file {path!r}: {e}") from e
    if params:
        docs.append(params_yaml(params))
    return "\n---\n".join(docs)
