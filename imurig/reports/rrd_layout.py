"""The viewer layout of the .rrd files: role colours, framed 3-D views, and the check that every
logged entity shows in some view of the recording's blueprint.

Roles
-----
Every series in a recording plays one role, with its own colour family (x, y, z: dark to light)
and its own word in the legend, so that a calibrated line is never mistaken for the truth:

* ``measured``: what the instrument gave (volts, counts, the recording under diagnosis), orange;
* ``calibrated``: the measurement through the estimated calibration, blue;
* ``truth``: the simulation's truth or the rig's reference, grey (drawn wider, underneath);
* ``twin``: the simulated twin of a recording, green; ``corrected_twin`` (the twin with the
  effects found), purple;
* ``residual``: measured or calibrated minus its reference, red; ``residual_after``: after the
  effects found, purple;
* ``estimate``: a filter's or a study's estimate, blue; ``uncalibrated``: a run without the
  calibration, red; ``bound``: a ±3σ envelope, grey.

Coverage
--------
:func:`uncovered` decides, with the viewer's own rule (``ViewContents``: the most specific
matching rule wins, ties to the last; ``path/**`` matches the path and its subtree), which
logged entities no view of a compatible kind shows: scalars need a time-series view, text a
text view, geometry and transforms a 3-D view, bar charts a bar-chart view.
:func:`views_in_rrd` and :func:`entities_in_rrd` read both sides back from a written file.
"""
from __future__ import annotations

import numpy as np
import rerun as rr
import rerun.blueprint as rrb
from rerun.encodings import TimeRange, TimeRangeBoundary

ROLES = {
    "measured": [(217, 95, 2), (253, 141, 60), (253, 190, 133)],
    "calibrated": [(8, 81, 156), (49, 130, 189), (107, 174, 214)],
    "truth": [(40, 40, 40, 110), (110, 110, 110, 110), (170, 170, 170, 130)],  # see-through: wide, underneath
    "twin": [(0, 109, 44, 150), (49, 163, 84, 150), (116, 196, 118, 160)],  # see-through: larger, underneath
    "corrected_twin": [(84, 39, 143), (128, 105, 185), (170, 160, 210)],
    "residual": [(165, 15, 21), (222, 45, 38), (251, 106, 74)],
    "residual_after": [(84, 39, 143), (128, 105, 185), (170, 160, 210)],
    "estimate": [(8, 81, 156), (49, 130, 189), (107, 174, 214)],
    "uncalibrated": [(203, 24, 29), (239, 59, 44), (252, 146, 114)],
    "bound": [(150, 150, 150), (150, 150, 150), (150, 150, 150)],
}
WIDTH = {"truth": 4.0, "twin": 3.0, "bound": 1.0}
MARKER = {"truth": 6.0, "twin": 6.0, "corrected_twin": 4.0}  # marker sizes; 3 otherwise
# the legend word of each role (underscores read badly in a legend)
WORD = {"corrected_twin": "corrected twin", "residual_after": "residual after"}

# archetype (first part of a chunk column name) -> the view class that draws it
_VIEW_OF = {"Scalars": "TimeSeries", "SeriesLines": "TimeSeries", "SeriesPoints": "TimeSeries",
            "TextDocument": "TextDocument", "BarChart": "BarChart"}
_SPATIAL = ("Points3D", "Boxes3D", "Ellipsoids3D", "Cylinders3D", "Capsules3D", "Arrows3D", "Transform3D",
            "LineStrips3D", "ViewCoordinates", "Mesh3D")
_VIEW_OF.update({a: "3D" for a in _SPATIAL})


def role_color(role: str, i: int = 0) -> tuple[int, ...]:
    """Colour of the ``i``-th series (0, 1, 2 = x, y, z) of ``role``."""
    fam = ROLES[role]
    return fam[i % len(fam)]


def legend(name: str, role: str, unit: str | None = None) -> str:
    """Legend text: ``"<name> <role word> [<unit>]"``, e.g. ``"f_x calibrated [m/s^2]"``."""
    word = WORD.get(role, role)
    return f"{name} {word}" + (f" [{unit}]" if unit else "")


def readable(values, unit: str) -> tuple[float, str]:
    """(factor, unit) that bring small values (residuals, errors) to labels the viewer's axis
    prints: when max |value| < 0.1 the unit takes the prefix m (x1e3) or µ (x1e6), e.g. m/s^2
    -> mm/s^2, rad/s -> mrad/s; a unit that takes no prefix gets ``10⁻³`` / ``10⁻⁶`` in front."""
    v = np.abs(np.asarray(values, dtype=float))
    big = float(np.nanmax(v)) if v.size and np.isfinite(v).any() else 0.0
    if big == 0.0 or big >= 0.1:
        return 1.0, unit
    factor, prefix = (1e3, "m") if big >= 1e-4 else (1e6, "µ")
    if unit.startswith(("m", "rad", "deg", "V", "s", "T")) and not unit.startswith("mm"):
        return factor, prefix + unit
    return factor, ("10⁻³ " if factor == 1e3 else "10⁻⁶ ") + (unit or "1")


def symmetric_range(*arrays) -> tuple[float, float] | None:
    """(-R, R) for residual plots: R the least of 1.2, 2, 2.5, 3, 4, 12 x 10^k at or above 1.05 max |value|.

    The viewer labels the y axis only at multiples of a power of ten whose spacing on screen is
    wide enough; residuals that span less than one such step (e.g. ±0.9) get a single label, 0,
    and a range of exactly ±10^k puts its other two labels on the plot's edges, where they are
    cut, and in a short plot more than some eight steps are too close to be labelled. A range
    of 1.2 to 4 steps puts the labels ±10^k (and more) inside the plot; above 4 steps the next
    power of ten is the step (R = 1.2 x 10^(k+1)).
    ``None`` when there is no finite value.
    """
    v = np.abs(np.concatenate([np.ravel(np.asarray(a, dtype=float)) for a in arrays]))
    v = v[np.isfinite(v)]
    if v.size == 0 or v.max() == 0.0:
        return None
    top = 1.05 * float(v.max())
    k = np.floor(np.log10(top))
    r = next(m * 10.0**k for m in (1.2, 2.0, 2.5, 3.0, 4.0, 12.0) if m * 10.0**k >= top)
    r = float(f"{r:.12g}")
    return -r, r


# ----------------------------------------------------------------------------- views

def device_eye(model, body: str, distance_m: float = 0.9, elevation_deg: float = 30.0,
               azimuth_deg: float = -60.0) -> rrb.EyeControls3D:
    """An orbit camera looking at ``body``'s origin (MuJoCo model at its rest pose), from
    ``distance_m`` away at the given elevation and azimuth (world z up)."""
    import mujoco  # the models are MuJoCo's; loaded with the rig writers anyway

    data = mujoco.MjData(model)
    mujoco.mj_kinematics(model, data)
    target = np.asarray(data.xpos[model.body(body).id], dtype=float)
    el, az = np.radians(elevation_deg), np.radians(azimuth_deg)
    offset = distance_m * np.array([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)])
    return rrb.EyeControls3D(kind=rrb.Eye3DKind.Orbital, position=target + offset, look_target=target,
                             eye_up=[0.0, 0.0, 1.0])


def rig_view(model, name: str = "rig", root: str = "world", device: str = "imu_mount",
             distance_m: float = 0.9) -> rrb.Spatial3DView:
    """The rig in 3-D, the camera framed on the device (``device`` body)."""
    return rrb.Spatial3DView(origin=root, name=name, eye_controls=device_eye(model, device, distance_m),
                             line_grid=rrb.LineGrid3D(visible=False))


def series_view(name: str, paths, origin: str = "/", legend_corner=rrb.Corner2D.RightTop,
                y_range: tuple[float, float] | None = None) -> rrb.TimeSeriesView:
    """A time-series view of exactly ``paths`` (entities or ``subtree/**``) over the whole
    recording (not a window around the time cursor); ``y_range`` fixes the y axis (see
    :func:`symmetric_range`)."""
    whole = TimeRange(start=TimeRangeBoundary.infinite(), end=TimeRangeBoundary.infinite())
    return rrb.TimeSeriesView(origin=origin, name=name, contents=[f"+ {p}" for p in paths],
                              axis_x=rrb.TimeAxis(view_range=whole),
                              axis_y=None if y_range is None else rrb.ScalarAxis(range=y_range),
                              plot_legend=rrb.PlotLegend(corner=legend_corner, visible=True))


def summary_view(name: str = "summary") -> rrb.TextDocumentView:
    return rrb.TextDocumentView(origin="summary", name=name)


def layout(root) -> rrb.Blueprint:
    """The blueprint of ``root`` (a container) with the side panels folded away (the viewport
    fills the window; the time panel stays as a thin bar with its play button)."""
    return rrb.Blueprint(root, rrb.BlueprintPanel(state="collapsed"), rrb.SelectionPanel(state="collapsed"),
                         rrb.TimePanel(state="collapsed"))


# ----------------------------------------------------------------------------- coverage

def _norm(path: str) -> str:
    return "/" + str(path).strip("/")


def _rules(origin: str, contents) -> list[tuple[bool, str, bool]]:
    """(include, path, recursive) per rule of a view's contents (``$origin`` substituted)."""
    lines = contents.splitlines() if isinstance(contents, str) else [str(c) for c in contents]
    out = []
    for line in (ln.strip() for ln in lines):
        if not line:
            continue
        include = not line.startswith("-")
        expr = line.lstrip("+-").strip().replace("$origin", _norm(origin))
        recursive = expr.endswith("/**") or expr == "**"
        out.append((include, _norm(expr[:-3] if recursive else expr), recursive))
    return out


def _shows(rules, entity: str) -> bool:
    """The viewer's rule: most specific matching rule wins (deeper path, then exact before
    recursive), ties to the last."""
    best, best_key = False, None
    for k, (include, path, recursive) in enumerate(rules):
        if recursive:
            hit = path == "/" or entity == path or entity.startswith(path + "/")
        else:
            hit = entity == path
        if hit:
            key = (len(path.strip("/").split("/")) if path != "/" else 0, not recursive, k)
            if best_key is None or key > best_key:
                best, best_key = include, key
    return best


def views_of(blueprint: rrb.Blueprint) -> list[tuple[str, str, list]]:
    """(view class, origin, rules) of every view in a Python blueprint."""
    out, stack = [], [blueprint.root_container]
    while stack:
        node = stack.pop()
        if hasattr(node, "class_identifier"):
            out.append((node.class_identifier, _norm(node.origin), _rules(node.origin, node.contents)))
        else:
            stack.extend(node.contents)
    return out


def views_in_rrd(path) -> list[tuple[str, str, list]]:
    """(view class, origin, rules) of every view in the blueprint stored in the .rrd ``path``."""
    reader = rr.chunk.RrdReader(str(path))
    stores = reader.blueprints()
    if not stores:
        return []
    cls, origin, contents = {}, {}, {}
    for chunk in reader.stream(store=stores[0]):
        b = chunk.to_record_batch()
        ent = str(chunk.entity_path)
        cols = set(b.schema.names)
        if "ViewBlueprint:class_identifier" in cols:
            cls[ent] = b.column("ViewBlueprint:class_identifier").to_pylist()[-1][0]
            origin[ent] = b.column("ViewBlueprint:space_origin").to_pylist()[-1][0]
        if "ViewContents:query" in cols:
            contents[ent.rsplit("/", 1)[0]] = b.column("ViewContents:query").to_pylist()[-1]
    return [(cls[v], _norm(origin[v]), _rules(origin[v], contents.get(v, ["$origin/**"]))) for v in cls]


def entities_in_rrd(path) -> dict[str, set[str]]:
    """{entity: the view classes its logged archetypes need} of the recording in ``path``."""
    out: dict[str, set[str]] = {}
    for chunk in rr.chunk.RrdReader(str(path)).stream():
        need = {_VIEW_OF[n.split(":")[0]] for n in chunk.to_record_batch().schema.names
                if ":" in n and n.split(":")[0] in _VIEW_OF}
        if need:
            out.setdefault(_norm(chunk.entity_path), set()).update(need)
    return out


def uncovered(entities: dict[str, set[str]], views) -> list[str]:
    """Sorted ``"<entity> (<view class>)"`` for every logged entity and the view class it needs
    that no view of that class shows."""
    missing = []
    for ent, need in entities.items():
        for kind in sorted(need):
            if not any(c == kind and _shows(rules, _norm(ent)) for c, _o, rules in views):
                missing.append(f"{ent} ({kind})")
    return sorted(missing)
