"""The fake InView's per-test record export: one CSV per test, the test's whole record, in a folder.

InView can export a sample as one CSV per test (``Markers, Displacement, Force, Time, DEPTH, LOAD, HARDNESS,
MODULUS, X/Y Axis Position`` with a units row and the marker rows gathered on top). The curve here is an
ideal Berkovich (A = 24.5 hc², an assumption for a fake, not a measured tip) loaded to the indent's depth at
max load, held, unloaded to 10 %, held for drift and unloaded; HARDNESS and MODULUS are the instrument's
values over the loading, so a reader finds the indent's own H and E at the End Of Loading marker. The raw
Displacement drifts at the indent's drift rate; DEPTH is drift-corrected, as InView writes it.
"""

from __future__ import annotations

_HEADER = ["Markers", "Displacement", "Force", "Time", "DEPTH", "LOAD", "HARDNESS", "MODULUS"]
_UNITS = ["", "nm", "mN", "s", "nm", "mN", "GPa", "GPa", "µm", "µm"]
_DT_S = 0.5  # s between samples (an assumption: InView's data rate is a method setting)


def record_csv(
    x_um: float,
    y_um: float,
    hardness_gpa: float | None,
    modulus_gpa: float | None,
    drift_nm_s: float,
    depth_nm: float,
    load_mn: float,
    invalid: float,
) -> bytes:
    """One test's record; ``None`` hardness/modulus (a failed indent) are written as ``invalid``."""
    samples: list[tuple[float, float]] = []  # (depth, load)
    markers: dict[str, int] = {"Surface Index": 0}
    for k in range(41):  # loading, P ∝ h² (a constant hardness)
        samples.append((depth_nm * k / 40, load_mn * (k / 40) ** 2))
    markers["End Of Loading Index"] = len(samples) - 1
    samples += [(depth_nm, load_mn)] * 5  # hold at peak
    recovered = 0.3 * depth_nm
    for k in range(1, 21):  # elastic unload to 10 % of the peak
        p = load_mn * (1 - 0.9 * k / 20)
        samples.append((depth_nm - recovered * (1 - (p / load_mn) ** (2 / 3)), p))
    markers["Begin Drift Data Index"] = len(samples)
    samples += [samples[-1]] * 20  # drift hold at 10 %
    markers["End Drift Data Index"] = len(samples) - 1
    for k in range(1, 6):
        samples.append((samples[-1][0], 0.1 * load_mn * (1 - k / 5)))

    h = invalid if hardness_gpa is None else hardness_gpa
    e = invalid if modulus_gpa is None else modulus_gpa

    def row(i: int, label: str = "") -> str:
        depth, load = samples[i]
        t = i * _DT_S
        loaded = i > 0 and load > 0.0
        cells = [label, repr(depth + drift_nm_s * t), repr(load), repr(t), repr(depth), repr(load)]
        cells += [repr(h), repr(e)] if loaded else ["", ""]
        return ",".join([*cells, repr(x_um), repr(y_um)])

    lines = [",".join([*_HEADER, "X Axis Position", "Y Axis Position"]), ",".join(_UNITS)]
    lines += [row(i, label) for label, i in sorted(markers.items())]  # gathered on top, by name
    lines += [row(i) for i in range(len(samples))]
    return ("\r\n".join(lines) + "\r\n").encode("utf-8-sig")
