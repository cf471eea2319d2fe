"""imurig.reports.viz: .rrd files are written atomically and read back with rerun's RrdReader."""

from pathlib import Path
import warnings

import mujoco
import numpy as np
import pytest
import rerun as rr

from imurig.reports import viz
from imurig.kernel.errors import OutputExistsError

# A fixed tilted base, a hinged arm (box) and an IMU child body with a site.
MJCF = """
<mujoco>
  <worldbody>
    <geom name="floor" type="plane" size="1 1 0.01"/>
    <body name="base" pos="0.1 0.2 0.5" quat="0.9238795 0 0.3826834 0">
      <geom type="cylinder" size="0.05 0.1" rgba="0.2 0.2 0.2 1"/>
      <body name="arm">
        <joint name="hinge" type="hinge" axis="0.3 0.4 0.8660254"/>
        <geom name="arm box" type="box" size="0.2 0.05 0.02" rgba="1 0 0 1"/>
        <geom type="capsule" size="0.01 0.05" pos="0 0 0.05"/>
        <geom type="sphere" size="0.02" pos="0.2 0 0"/>
        <body name="imu" pos="0.15 0.01 0.03" quat="0.5 0.5 0.5 0.5">
          <geom type="box" size="0.02 0.02 0.01"/>
          <site name="imu" size="0.005"/>
        </body>
      </body>
    </body>
  </worldbody>
</mujoco>
"""


def _rows(path, entity):
    """All temporal rows of ``entity`` in the rrd: {column: array}, sorted by time."""
    cols, t = {}, []
    for chunk in rr.chunk.RrdReader(path).stream():
        if chunk.entity_path == "/" + entity and not chunk.is_static:
            batch = chunk.to_record_batch()
            t.append(batch.column("time").cast("int64").to_numpy() * 1e-9)  # duration [ns] -> s
            for name in batch.schema.names:
                if name != "time":
                    cols.setdefault(name, []).extend(batch.column(name).to_pylist())
    t = np.concatenate(t)
    order = np.argsort(t, kind="stable")
    return t[order], {k: [v[i] for i in order] for k, v in cols.items() if k != "rerun.controls.RowId"}


def _quat_mul(a, b):  # w,x,y,z
    return np.array([a[0] * b[0] - a[1:] @ b[1:], *(a[0] * b[1:] + b[0] * a[1:] + np.cross(a[1:], b[1:]))])


def _rot(q, v):  # rotate v by w,x,y,z quaternion
    return _quat_mul(_quat_mul(q, np.r_[0.0, v]), q * [1, -1, -1, -1])[1:]


def _write(path, model, t, qpos, **kw):
    with viz.RrdWriter(path, recording_name="test", **kw) as w:
        viz.log_mujoco_model(w, model)
        viz.log_body_poses(w, model, t[::20], qpos)
        viz.log_frame_axes(w, viz.body_path(model, model.body("imu").id))
        viz.log_scalars(w, "signals/raw", t, {"acc_x": np.sin(t), "acc_y": np.cos(t)},
                        units={"acc_x": "V", "acc_y": "V"})
        viz.log_text(w, "summary", "# Summary\n\n| a | b |\n|---|---|\n| 1 | 2 |")


def test_rrd_roundtrip(tmp_path):
    model = mujoco.MjModel.from_xml_string(MJCF)
    t = np.arange(1000) * 0.01
    qpos = np.linspace(0.0, 1.3, 50)[:, None]
    out = tmp_path / "run.rrd"
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # no deprecated rerun API
        _write(out, model, t, qpos)

    assert out.stat().st_size > 0
    assert sorted(p.name for p in tmp_path.iterdir()) == ["run.rrd"]  # no temp file left
    assert rr.bindings.check_for_rrd_footer(str(out))
    assert viz.body_path(model, model.body("imu").id) == "world/base/arm/imu"

    with pytest.raises(OutputExistsError, match="overwrite=True"):
        viz.RrdWriter(out)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["run.rrd"]

    # scalars round-trip
    ts, cols = _rows(out, "signals/raw/acc_x")
    np.testing.assert_allclose(ts, t, atol=1e-9)
    np.testing.assert_allclose(np.concatenate(cols["Scalars:scalars"]), np.sin(t))

    # body transforms: compose read-back (xyzw) relative poses and compare to MuJoCo's world pose
    data = mujoco.MjData(model)
    data.qpos[:] = qpos[-1]
    mujoco.mj_kinematics(model, data)
    pos, quat = np.zeros(3), np.array([1.0, 0, 0, 0])
    for entity in ("world/base", "world/base/arm", "world/base/arm/imu"):
        ts, cols = _rows(out, entity)
        assert len(ts) == 50 and ts[-1] == pytest.approx(t[::20][-1])
        tr = np.array(cols["Transform3D:translation"][-1][0])
        x, y, z, w = cols["Transform3D:quaternion"][-1][0]
        q_rel = np.array([w, x, y, z])
        pos, quat = pos + _rot(quat, tr), _quat_mul(quat, q_rel)
    imu = model.body("imu").id
    np.testing.assert_allclose(pos, data.xpos[imu], atol=1e-6)
    assert abs(quat @ data.xquat[imu]) == pytest.approx(1.0, abs=1e-6)
    np.testing.assert_allclose(quat * np.sign(quat @ data.xquat[imu]), data.xquat[imu], atol=1e-6)

    # static content is there too
    static = {c.entity_path for c in rr.chunk.RrdReader(out).stream() if c.is_static}
    assert {"/world/base/arm/geom_arm\\ box", "/world/geom_floor", "/summary", "/signals/raw/acc_x"} <= static

    # overwrite=True replaces the file
    _write(out, model, t, qpos, overwrite=True)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["run.rrd"]


def test_error_leaves_no_file(tmp_path):
    out = tmp_path / "bad.rrd"
    with pytest.raises(RuntimeError):
        with viz.RrdWriter(out) as w:
            viz.log_text(w, "summary", "partial")
            raise RuntimeError("boom")
    assert list(tmp_path.iterdir()) == []


def test_body_quat_override(tmp_path):
    model = mujoco.MjModel.from_xml_string(MJCF)
    q0 = model.body("imu").quat.copy()
    mount = np.tile([0.0, 0.0, 0.0, 1.0], (3, 1))  # 180 deg about z, w,x,y,z
    with viz.RrdWriter(tmp_path / "o.rrd", blueprint=None) as w:
        viz.log_body_poses(w, model, [0.0, 1.0, 2.0], np.zeros((3, 1)), body_quat_overrides={"imu": mount})
    np.testing.assert_array_equal(model.body("imu").quat, q0)  # model restored
    _, cols = _rows(tmp_path / "o.rrd", "world/base/arm/imu")
    np.testing.assert_allclose(np.abs(cols["Transform3D:quaternion"][-1][0]), [0, 0, 1, 0], atol=1e-6)


def test_tilt_table_logs(tmp_path):
    try:
        from imurig.rigs.mujoco_rig import load_model
        model = load_model("tilt_table.xml")
    except ImportError:
        model = mujoco.MjModel.from_xml_path(str(Path(__file__).parents[1] / "assets" / "tilt_table.xml"))
    out = tmp_path / "tilt.rrd"
    with viz.RrdWriter(out) as w:
        viz.log_mujoco_model(w, model)
        viz.log_body_poses(w, model, np.arange(10) * 0.1, np.zeros((10, model.nq)))
        viz.log_frame_axes(w, viz.body_path(model, model.body("imu_mount").id))
    paths = {c.entity_path for c in rr.chunk.RrdReader(out).stream()}
    assert "/world/pedestal/base/cradle/platform/imu_mount/geom_imu_box" in paths
    assert sum("/geom_" in p for p in paths) == model.ngeom
