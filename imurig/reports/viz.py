"""Rerun (.rrd) logging of the MuJoCo rig, the IMU frame and signal time series.

This module and :mod:`imurig.reports.rrd_layout` (colours, views, the coverage check) are the
only ones that talk to rerun. Inputs are plain numpy arrays and MuJoCo
models; nothing here touches rerun's global/thread-local recording state and nothing
connects to a viewer. Open a written file with ``rerun file.rrd``.

Conventions
-----------
* Entity tree: ``<root>/<body>/<child body>/...`` following ``model.body_parentid`` by
  body names (``world`` is body 0), e.g. ``world/pedestal/base/cradle``. Each body
  entity carries its pose *relative to its parent body* (Transform3D, parent <- child),
  so the viewer composes the world pose. Geoms are children ``<body path>/geom_<name|id>``
  with a static local pose (geom_pos, geom_quat).
* Quaternions: MuJoCo uses (w, x, y, z); rerun wants (x, y, z, w). The conversion
  happens only in this module (``_xyzw``); every public input is MuJoCo-ordered.
* Time: a single timeline ``"time"`` holding durations in seconds (``TIMELINE``).
"""

from __future__ import annotations

import os
import tempfile
import uuid
import warnings
from pathlib import Path

import mujoco
import numpy as np
import rerun as rr
import rerun.blueprint as rrb

from imurig.kernel.errors import OutputExistsError
from imurig.kernel.quaternion import q_conj, q_mult, q_rotate
from imurig.reports.rrd_layout import _VIEW_OF, MARKER, WIDTH, legend, role_color, uncovered, views_of
from imurig.rigs.batch_kinematics import forward_kinematics, kinematics_by_row

TIMELINE = "time"
_SOLID = rr.components.FillMode.Solid

__all__ = [
    "TIMELINE",
    "RrdLayoutWarning",
    "RrdWriter",
    "body_path",
    "break_gaps",
    "default_blueprint",
    "log_body_poses",
    "log_frame_axes",
    "log_mujoco_model",
    "log_scalars",
    "log_text",
]


def default_blueprint(root: str = "world") -> rrb.Blueprint:
    """Layout: 3-D view of ``root`` left; raw / calibrated series and the summary right."""
    return rrb.Blueprint(
        rrb.Horizontal(
            rrb.Spatial3DView(origin=root, name="rig"),
            rrb.Vertical(
                rrb.TimeSeriesView(origin="signals/raw", name="raw"),
                rrb.TimeSeriesView(origin="signals/calibrated", name="calibrated"),
                rrb.TextDocumentView(origin="summary", name="summary"),
            ),
        ),
        collapse_panels=False,
    )


class RrdLayoutWarning(UserWarning):
    """A logged entity lies outside every view of the recording's blueprint (the viewer would
    not show it). The test suite turns this warning into an error."""


class RrdWriter:
    """Context manager writing one recording to an ``.rrd`` file, atomically.

    Data goes to a temporary file next to ``path``; on a clean ``__exit__`` (or
    :meth:`close`) the file is finalized (footer written) and renamed onto ``path``. On
    an exception (or :meth:`abort`) the temporary file is deleted, so no half-written
    ``.rrd`` is ever left at ``path``.

    Parameters
    ----------
    path : output ``.rrd`` path. Its folder must exist.
    application_id : rerun application id (groups recordings in the viewer).
    recording_name : optional human-readable name shown in the viewer.
    overwrite : replace an existing ``path``; otherwise :class:`OutputExistsError`.
    blueprint : ``True`` for :func:`default_blueprint`, ``None``/``False`` for none,
        or any rerun blueprint, sent as the default layout with the recording.

    Attributes
    ----------
    stream : rr.RecordingStream
        The (non-global) stream; pass it around or use the ``log_*`` helpers.
    path : Path
    entities : dict[str, set[str]]
        Every entity the ``log_*`` helpers (or :meth:`log`) wrote, with the view class each needs.
        On close, those that no view of the blueprint shows raise :class:`RrdLayoutWarning`.
    """

    def __init__(self, path, application_id: str = "imurig", recording_name: str | None = None,
                 *, overwrite: bool = False, blueprint=True):
        self.path = Path(path)
        self.overwrite = overwrite
        self._check_target()
        fd, tmp = tempfile.mkstemp(prefix=f".{self.path.name}.", suffix=".tmp", dir=self.path.parent or ".")
        os.close(fd)
        mask = os.umask(0)
        os.umask(mask)
        os.chmod(tmp, 0o666 & ~mask)  # the user's umask, not mkstemp's 0600
        self._tmp = Path(tmp)
        self._open = True
        self.entities: dict[str, set[str]] = {}
        try:
            self.stream = rr.RecordingStream(application_id, recording_id=uuid.uuid4())
            bp = default_blueprint() if blueprint is True else (blueprint or None)
            self.blueprint = bp
            self.stream.save(self._tmp, default_blueprint=bp)
            if recording_name:
                self.stream.send_recording_name(recording_name)
        except BaseException:
            self._tmp.unlink(missing_ok=True)
            raise

    def _check_target(self) -> None:
        if self.path.exists() and not self.overwrite:
            raise OutputExistsError(
                f"{self.path} already exists; pass overwrite=True (or --overwrite on the command line) "
                "to replace it, or choose another output path.")

    def log(self, entity: str, *archetypes, static: bool = False) -> None:
        """``stream.log`` that also notes ``entity`` and the view class its archetypes need."""
        self.note(entity, *(type(a).__name__ for a in archetypes))
        self.stream.log(entity, *archetypes, static=static)

    def send_default_blueprint(self, blueprint) -> None:
        """Send ``blueprint`` as the recording's default layout now, for a writer opened with none (when
        the layout depends on data known only after the first entities are logged): the file then holds
        what ``blueprint=`` at opening would have put there, and :meth:`close` checks it the same way."""
        self.blueprint = blueprint
        self.stream.send_blueprint(blueprint, make_active=False, make_default=True)

    def note(self, entity: str, *archetype_names: str) -> None:
        """Record that ``entity`` holds the named archetypes (for the coverage check)."""
        need = self.entities.setdefault("/" + entity.strip("/"), set())
        need.update(_VIEW_OF[n] for n in archetype_names if n in _VIEW_OF)

    def uncovered(self) -> list[str]:
        """Logged entities no view of the blueprint shows (empty without a blueprint)."""
        if not isinstance(self.blueprint, rrb.Blueprint):
            return []
        return uncovered(self.entities, views_of(self.blueprint))

    def close(self) -> Path:
        """Finalize the file and move it onto ``path``. Returns ``path``. Idempotent."""
        if not self._open:
            return self.path
        self._open = False
        missing = self.uncovered()
        if missing:
            warnings.warn(RrdLayoutWarning(f"{self.path.name}: logged but in no view of its blueprint: "
                                           + ", ".join(missing)), stacklevel=2)
        try:
            self.stream.flush()
            self.stream.disconnect()  # finalizes the file sink: writes the rrd footer
            self._check_target()
            os.replace(self._tmp, self.path)
        except BaseException:
            self._tmp.unlink(missing_ok=True)
            raise
        return self.path

    def abort(self) -> None:
        """Stop writing and delete the temporary file; ``path`` is left untouched."""
        if self._open:
            self._open = False
            try:
                self.stream.disconnect()
            finally:
                self._tmp.unlink(missing_ok=True)

    def __enter__(self) -> RrdWriter:
        return self

    def __exit__(self, exc_type, exc, tb) -> None:
        if exc_type is None:
            self.close()
        else:
            self.abort()


# ----------------------------------------------------------------------------- helpers

def _xyzw(q_wxyz: np.ndarray) -> np.ndarray:
    """MuJoCo (..., 4) w,x,y,z -> rerun (..., 4) x,y,z,w."""
    return np.asarray(q_wxyz, dtype=float)[..., [1, 2, 3, 0]]


def _name(model: mujoco.MjModel, obj: mujoco.mjtObj, idx: int) -> str:
    return mujoco.mj_id2name(model, obj, idx) or ""


def body_path(model: mujoco.MjModel, body_id: int, root: str = "world") -> str:
    """Entity path of a body: ``root/<ancestor names...>/<name>``; body 0 is ``root``.

    Unnamed bodies are called ``body_<id>``; names are escaped for rerun.
    """
    parts = []
    b = int(body_id)
    while b != 0:
        parts.append(rr.escape_entity_path_part(_name(model, mujoco.mjtObj.mjOBJ_BODY, b) or f"body_{b}"))
        b = int(model.body_parentid[b])
    return "/".join([root, *reversed(parts)])


def _time_column(time_s) -> rr.TimeColumn:
    return rr.TimeColumn(TIMELINE, duration=np.asarray(time_s, dtype=float))


# ----------------------------------------------------------------------------- logging

def log_mujoco_model(w: RrdWriter, model: mujoco.MjModel, root: str = "world") -> None:
    """Log every geom of ``model`` as static geometry under its body's entity.

    Each geom goes to ``body_path(body)/geom_<name or geom id>`` with a static
    Transform3D = geom pose in the body frame (geom_pos, geom_quat) and a shape in the geom
    frame: box -> Boxes3D, cylinder -> Cylinders3D (along z, length = 2*half-height),
    capsule -> Capsules3D, sphere/ellipsoid -> Ellipsoids3D, plane -> thin box (size 0 =
    infinite is drawn 1 m), other types (mesh, hfield, sdf) are skipped. Colors from
    geom_rgba (mat_rgba if a material sets the color). Also sets ``root`` to z-up.
    """
    s = w
    s.log(root, rr.ViewCoordinates.RIGHT_HAND_Z_UP, static=True)
    G = mujoco.mjtGeom
    for g in range(model.ngeom):
        size = np.asarray(model.geom_size[g], dtype=float)
        rgba = np.asarray(model.geom_rgba[g], dtype=float)
        mat = int(model.geom_matid[g])
        if mat >= 0 and np.allclose(rgba, [0.5, 0.5, 0.5, 1.0]):
            rgba = np.asarray(model.mat_rgba[mat], dtype=float)
        color = np.round(np.clip(rgba, 0, 1) * 255).astype(np.uint8)
        kind = int(model.geom_type[g])
        if kind == G.mjGEOM_BOX:
            shape = rr.Boxes3D(half_sizes=[size], colors=[color], fill_mode=_SOLID)
        elif kind == G.mjGEOM_CYLINDER:
            shape = rr.Cylinders3D(radii=[size[0]], lengths=[2 * size[1]], colors=[color], fill_mode=_SOLID)
        elif kind == G.mjGEOM_CAPSULE:  # rerun capsules run from z=0 to z=length
            shape = rr.Capsules3D(radii=[size[0]], lengths=[2 * size[1]], translations=[[0, 0, -size[1]]],
                                  colors=[color], fill_mode=_SOLID)
        elif kind == G.mjGEOM_SPHERE:
            shape = rr.Ellipsoids3D(radii=[size[0]], colors=[color], fill_mode=_SOLID)
        elif kind == G.mjGEOM_ELLIPSOID:
            shape = rr.Ellipsoids3D(half_sizes=[size], colors=[color], fill_mode=_SOLID)
        elif kind == G.mjGEOM_PLANE:
            hx, hy = (v if v > 0 else 1.0 for v in size[:2])
            shape = rr.Boxes3D(half_sizes=[[hx, hy, 1e-3]], centers=[[0, 0, -1e-3]], colors=[color],
                               fill_mode=_SOLID)
        else:
            continue
        name = _name(model, mujoco.mjtObj.mjOBJ_GEOM, g)
        entity = f"{body_path(model, model.geom_bodyid[g], root)}/geom_{rr.escape_entity_path_part(name) if name else g}"
        s.log(entity, rr.Transform3D(translation=model.geom_pos[g], quaternion=_xyzw(model.geom_quat[g])),
              static=True)
        s.log(entity, shape, static=True)


def log_body_poses(w: RrdWriter, model: mujoco.MjModel, time_s, qpos,
                   body_quat_overrides: dict[str, np.ndarray] | None = None, root: str = "world") -> None:
    """Log every body's pose relative to its parent over time (one send_columns per body).

    Parameters
    ----------
    time_s : (T,) seconds on the ``"time"`` timeline.
    qpos : (T, nq) joint positions.
    body_quat_overrides : {body name: (T, 4) w,x,y,z} replaces ``model.body_quat`` of that
        body (its fixed orientation in the parent frame, e.g. a per-run IMU mounting) row by
        row. ``model`` is restored afterwards.

    Forward kinematics for all rows at once (:mod:`imurig.rigs.batch_kinematics`; free or ball joints:
    ``mj_kinematics`` row by row, meant for display rates).
    The relative pose is parent <- child: t = R_p^T (x_b - x_p), q = q_p^* q_b.
    """
    time_s = np.asarray(time_s, dtype=float)
    qpos = np.asarray(qpos, dtype=float).reshape(len(time_s), -1)
    if qpos.shape[1] != model.nq:
        raise ValueError(f"qpos has {qpos.shape[1]} columns but the model has nq={model.nq}")
    overrides = {}
    for name, q in (body_quat_overrides or {}).items():
        bid = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, name)
        if bid < 0:
            raise ValueError(f"body_quat_overrides: no body named {name!r} in the model")
        q = np.broadcast_to(np.asarray(q, dtype=float), (len(time_s), 4))
        overrides[bid] = q / np.linalg.norm(q, axis=1, keepdims=True)
    nb = model.nbody
    fk = forward_kinematics(model, qpos, overrides)   # hinge and slide trees: all rows at once
    xpos, xquat = fk if fk is not None else kinematics_by_row(model, qpos, overrides)
    parent = np.asarray(model.body_parentid)
    qp_inv = q_conj(xquat[:, parent])
    rel_pos = q_rotate(qp_inv, xpos - xpos[:, parent])
    rel_quat = q_mult(qp_inv, xquat)
    times = _time_column(time_s)
    for b in range(1, nb):
        w.note(body_path(model, b, root), "Transform3D")
        w.stream.send_columns(body_path(model, b, root), indexes=[times],
                              columns=rr.Transform3D.columns(translation=rel_pos[:, b],
                                                             quaternion=_xyzw(rel_quat[:, b])))


def log_frame_axes(w: RrdWriter, entity: str, length: float = 0.15) -> None:
    """Static x (red), y (green), z (blue) arrows of ``length`` m at ``entity``'s origin."""
    w.log(entity, rr.Arrows3D(vectors=np.eye(3) * length,
                                     colors=[[255, 0, 0], [0, 255, 0], [0, 0, 255]],
                                     labels=["x", "y", "z"], radii=length / 50), static=True)


def log_scalars(w: RrdWriter, entity_prefix: str, time_s, series: dict[str, np.ndarray],
                units: dict[str, str] | None = None, role: str | None = None, points: bool = False,
                colors: dict[str, tuple] | None = None, labels: dict[str, str] | None = None,
                sequence: str | None = None) -> None:
    """Log each (T,) series to ``entity_prefix/<name>`` with one send_columns call.

    Without ``role`` a static SeriesLines name ``"<name> [<unit>]"`` is logged (unit when
    ``units`` has the name). With a ``role`` (see :mod:`imurig.reports.rrd_layout`) the legend
    reads ``"<name> <role> [<unit>]"`` and the i-th series takes the role's i-th colour (the
    truth drawn wider); ``colors`` {name: rgb} and ``labels`` {name: legend} override them.
    ``points=True`` draws markers (SeriesPoints) instead of lines: for values per position,
    step or run rather than per sample. ``sequence`` puts the values on a sequence timeline of
    that name (``time_s`` then holds integers, e.g. run numbers) instead of ``"time"``.
    """
    time_s = np.asarray(time_s, dtype=float)
    times = _time_column(time_s) if sequence is None else rr.TimeColumn(sequence, sequence=time_s.astype(np.int64))
    units = units or {}
    for i, (name, values) in enumerate(series.items()):
        values = np.asarray(values, dtype=float)
        if values.shape != time_s.shape:
            raise ValueError(f"series {name!r} has shape {values.shape}, expected {time_s.shape} like time_s")
        entity = f"{entity_prefix}/{rr.escape_entity_path_part(name)}"
        if role is None:
            label = f"{name} [{units[name]}]" if name in units else name
        else:
            label = legend(name, role, units.get(name))
        style = {"names": (labels or {}).get(name) or label}
        if role is not None or name in (colors or {}):
            style["colors"] = [(colors or {}).get(name) or role_color(role, i)]
        if points:
            w.log(entity, rr.SeriesPoints(**style, marker_sizes=[MARKER.get(role, 3.0)]), static=True)
        else:
            w.log(entity, rr.SeriesLines(**style, widths=[WIDTH.get(role, 1.5)]), static=True)
        w.note(entity, "Scalars")
        w.stream.send_columns(entity, indexes=[times], columns=rr.Scalars.columns(scalars=values))


def break_gaps(time_s, series: dict[str, np.ndarray], factor: float = 5.0):
    """(time_s, series) with a NaN sample in the middle of every gap longer than ``factor`` times
    the median sample interval: the viewer breaks a line at a NaN instead of drawing a straight
    line across the gap (between runs, blocks or manoeuvres)."""
    t = np.asarray(time_s, dtype=float)
    dt = np.diff(t)
    if dt.size < 2 or not np.any(dt > 0):
        return t, series
    cut = np.flatnonzero(dt > factor * np.median(dt[dt > 0]))
    if cut.size == 0:
        return t, series
    t_new = np.insert(t, cut + 1, 0.5 * (t[cut] + t[cut + 1]))
    return t_new, {k: np.insert(np.asarray(v, dtype=float), cut + 1, np.nan) for k, v in series.items()}


def log_text(w: RrdWriter, entity: str, markdown: str) -> None:
    """Static markdown TextDocument at ``entity`` (e.g. ``"summary"``)."""
    w.log(entity, rr.TextDocument(markdown, media_type=rr.MediaType.MARKDOWN), static=True)


def log_points(w: RrdWriter, entity: str, points: np.ndarray, color=(200, 200, 200), radius: float = 0.01) -> None:
    """Static Points3D (n, 3) at ``entity`` (e.g. measured and calibrated magnetic field in uT)."""
    pts = np.asarray(points, dtype=np.float32)
    w.log(entity, rr.Points3D(pts, colors=[color], radii=radius), static=True)


def log_sphere(w: RrdWriter, entity: str, radius: float, color=(80, 200, 120, 60)) -> None:
    """A static wire sphere of ``radius`` at the entity's origin (e.g. the IGRF field magnitude)."""
    w.log(entity, rr.Ellipsoids3D(half_sizes=[[radius] * 3], colors=[color],
                                         fill_mode=rr.components.FillMode.MajorWireframe), static=True)
