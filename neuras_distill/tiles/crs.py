"""A tileset placed on the globe: the root transform from a projected CRS to Earth-centred coordinates (this module
owns every pyproj call).

A scene distilled in a projected CRS (a UTM zone, a national grid: x easting, y northing, z ellipsoidal height,
metres) is placed by ``tiles merge --crs EPSG:XXXXX``. 3D Tiles wants its content in ECEF (EPSG:4978, metres
from the Earth's centre), reached through the root's ``transform``. The map from the projected CRS to ECEF is
not linear: the grid's north turns from true north (meridian convergence), its metre is not a metre (the scale
factor), and the Earth curves away. The root transform is that map's first-order expansion at the scene box's
centre ``o``:

    ECEF(p) ~ ECEF(o) + J (p - o),   J = d ECEF / d p at o (central differences over 1 m, in float64)

applied to tileset-frame points ``t = M p`` (``tileset.tileset_frame``), so the 4x4 is ``[J M^T | ECEF(o) - J o]``.
It is exact at ``o``; a point ``d`` metres away is off by about ``d^2 / (2 R)`` (the curvature; 2.8 cm at
600 m). :func:`placement_error` measures it at given points against pyproj's exact transform.
"""

from __future__ import annotations

import numpy as np

from ..errors import BadInputError, require

#: Earth-centred, Earth-fixed (metres), the frame 3D Tiles places content in.
ECEF = "EPSG:4978"
#: Step of the central differences (metres of the projected CRS).
STEP_M = 1.0


def _pyproj():
    try:
        import pyproj  # noqa: PLC0415
    except ImportError:
        raise BadInputError("--crs needs pyproj (pip install neuras-distill[geo]); or merge without --crs for a "
                            "local frame") from None
    return pyproj


def projected_crs(text: str):
    """The pyproj CRS of ``--crs`` (e.g. ``EPSG:32633``), made 3D (its z an ellipsoidal height); BadInputError
    for an unknown or non-projected CRS."""
    pyproj = _pyproj()
    try:
        crs = pyproj.CRS.from_user_input(text)
    except pyproj.exceptions.CRSError:
        raise BadInputError(f"--crs {text!r} is not a coordinate reference system PROJ knows; pass a projected "
                            "CRS as EPSG:XXXXX (e.g. EPSG:32633 for UTM zone 33N)") from None
    require(crs.is_projected, f"--crs {text} ({crs.name}) is not a projected CRS: the scene's x, y must be metres "
                              "east and north; pass a projected CRS such as a UTM zone (EPSG:326NN / 327NN)")
    return crs.to_3d()


def _to_ecef(crs):
    return _pyproj().Transformer.from_crs(crs, ECEF, always_xy=True)


def ecef_points(crs, points: np.ndarray) -> np.ndarray:
    """(N, 3) float64 points of the projected ``crs`` in ECEF, by pyproj's exact transform."""
    p = np.asarray(points, np.float64).reshape(-1, 3)
    x, y, z = _to_ecef(crs).transform(p[:, 0], p[:, 1], p[:, 2])
    out = np.stack([np.asarray(x), np.asarray(y), np.asarray(z)], axis=1)
    require(bool(np.isfinite(out).all()), "the scene's coordinates are outside the CRS's area: PROJ gave no "
                                          "Earth position; check --crs against the capture's coordinates")
    return out


def root_transform(crs, origin: np.ndarray, frame: np.ndarray) -> np.ndarray:
    """(4, 4) float64 map from the tileset frame ``t = frame @ p`` to ECEF, exact at the world point ``origin``."""
    o = np.asarray(origin, np.float64).reshape(3)
    steps = np.concatenate([o + STEP_M * np.eye(3), o - STEP_M * np.eye(3), o[None]])
    e = ecef_points(crs, steps)
    jac = (e[:3] - e[3:6]).T / (2.0 * STEP_M)              # column k: d ECEF / d p_k
    out = np.eye(4)
    out[:3, :3] = jac @ np.asarray(frame, np.float64).T
    out[:3, 3] = e[6] - jac @ o
    return out


def placement_error(crs, transform: np.ndarray, frame: np.ndarray, points: np.ndarray) -> np.ndarray:
    """(N,) metres between ``transform`` applied to the tileset-frame points of world ``points`` (N, 3) and
    pyproj's ECEF of the same points."""
    p = np.asarray(points, np.float64).reshape(-1, 3)
    t = p @ np.asarray(frame, np.float64).T
    placed = t @ transform[:3, :3].T + transform[:3, 3]
    return np.linalg.norm(placed - ecef_points(crs, p), axis=1)


def geodetic(crs, point: np.ndarray) -> tuple[float, float, float]:
    """(longitude, latitude in degrees, ellipsoidal height in metres) of one projected ``point``."""
    to_geo = _pyproj().Transformer.from_crs(crs, crs.geodetic_crs.to_3d(), always_xy=True)
    lon, lat, h = to_geo.transform(*np.asarray(point, np.float64).reshape(3))
    return float(lon), float(lat), float(h)
