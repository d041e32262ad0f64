"""A trace's channels as the solver's rows: the vector channels (``pose``, ``position``,
``orientation``, ``tilt``) and the row channels they map to, and the noise a trace states
(header ``sigma``, per reading) as sigma per row channel of a measurement model."""
from __future__ import annotations

# vector channels of a trace and the solver's row channels they map to
VECTOR_CHANNELS = {"pose": ("x", "y", "z", "phi"),
                   "position": ("x", "y", "z"),
                   "orientation": ("alpha", "beta", "gamma"),
                   "tilt": ("roll", "pitch")}
# the same for a robot file's 6-row pose
SERIAL_POSE = ("x", "y", "z", "roll", "pitch", "yaw")


def solver_sigma(model, trace) -> dict | None:
    """The ``sigma`` (per reading) of a trace (:class:`station.recording.trace.Trace`) as
    sigma per solver row channel of ``model``,
    where the residual is a reading minus a prediction."""
    sig = trace.header.get("sigma") or {}
    comps = trace.header.get("components")
    out = {}
    for key, v in sig.items():
        if key == "distance" and getattr(model, "residual", "plain") == "squared":
            continue  # D^2 residual: its noise 2 D sigma differs per pose; estimate instead
        if key in model.channels and not isinstance(v, list):
            out[key] = float(v)
        elif key in VECTOR_CHANNELS:
            names = tuple(comps) if key == "orientation" and comps else VECTOR_CHANNELS[key]
            if key == "pose" and "roll" in model.channels:
                names = SERIAL_POSE
            vals = v if isinstance(v, list) else [v] * len(names)
            out.update({n: float(x) for n, x in zip(names, vals) if n in model.channels})
    return out or None
