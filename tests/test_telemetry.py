"""The telemetry's MCAP of a run: every channel, one message per frame where it says so, values equal
to the run's log; the export of the run folder gives the same channels; bad run folders exit 2."""

from __future__ import annotations

import itertools
import json
import math
import shutil
from pathlib import Path

import numpy as np
import pytest
from mcap.reader import make_reader
from mcap_protobuf.decoder import DecoderFactory

from capsule_mpc.cli import main
from capsule_mpc.experiments.runs import export_run_arm
from capsule_mpc.paths import ReferencePath
from capsule_mpc.sim import ClosedLoop, write_run
from capsule_mpc.telemetry.layout import layout_json
from capsule_mpc.telemetry.observer import Telemetry
from capsule_mpc.telemetry.topics import TOPICS

REPO = Path(__file__).resolve().parents[1]
#: A corner: a short MPC run with a prediction and a turn.
CORNER = ReferencePath(np.array([[0.0, 0.0], [0.03, 0.0], [0.03, 0.02]]), False, 0.02)
PER_FRAME = (
    "/tf",
    "/capsule/true",
    "/epm/pose",
    "/reference/pose",
    "/mpc/prediction",
    "/run/tracking",
    "/run/command",
    "/arm/joint_states",
)
ONCE = ("/rig/scene", "/tf_static", "/robot_description")


def read_mcap(path: Path) -> tuple[dict[str, dict], dict[str, list[tuple[int, object]]], list]:
    """(topic -> {schema, encoding, count}, topic -> [(log time, decoded message)], metadata)."""
    decoders = DecoderFactory()
    channels: dict[str, dict] = {}
    messages: dict[str, list[tuple[int, object]]] = {}
    with path.open("rb") as fh:
        reader = make_reader(fh)
        summary = reader.get_summary()
        assert summary is not None and summary.statistics is not None
        for cid, ch in summary.channels.items():
            schema = summary.schemas[ch.schema_id]
            channels[ch.topic] = {
                "schema": schema.name,
                "encoding": ch.message_encoding,
                "count": summary.statistics.channel_message_counts.get(cid, 0),
            }
        for schema, channel, message in reader.iter_messages(log_time_order=True):
            if channel.message_encoding == "json":
                decoded: object = json.loads(message.data)
            else:
                decode = decoders.decoder_for(channel.message_encoding, schema)
                assert decode is not None, channel.topic
                decoded = decode(message.data)
            messages.setdefault(channel.topic, []).append((message.log_time, decoded))
        metadata = list(reader.iter_metadata())
    return channels, messages, metadata


@pytest.fixture(scope="module")
def mpc_run(fast, tmp_path_factory):
    """An MPC run on the robot arm with the telemetry, and its run folder (log, summary, arm files)."""
    scenario = fast.model_copy(update={"sim": fast.sim.model_copy(update={"settle_s": 0.3, "tail_s": 0.5})})
    folder = tmp_path_factory.mktemp("run")
    mcap = folder / "run.mcap"
    with Telemetry(mcap, run_info={"config": "test"}) as tel:
        result = ClosedLoop(scenario, "mpc", CORNER, seed=1).run([tel])
    write_run(result, folder)
    export_run_arm(result, folder)
    channels, messages, metadata = read_mcap(mcap)
    return result, folder, channels, messages, metadata


def test_every_channel_with_its_schema_and_one_message_per_frame(mpc_run):
    result, _folder, channels, _messages, _metadata = mpc_run
    n = len(result.log["t_s"])
    assert set(channels) == {t.name for t in TOPICS}
    for topic in TOPICS:
        assert channels[topic.name]["schema"] == topic.schema, topic.name
        expected = "protobuf" if topic.schema.startswith("foxglove.") else "json"
        assert channels[topic.name]["encoding"] == expected, topic.name
    for name in PER_FRAME:
        assert channels[name]["count"] == n, name
    for name in ONCE:
        assert channels[name]["count"] == 1, name
    measured = int(np.count_nonzero(np.isfinite(result.log["meas_x_m"])))
    assert channels["/capsule/measured"]["count"] == measured
    assert 0 < channels["/capsule/estimate"]["count"] <= n
    assert channels["/run/events"]["count"] >= 3  # start, path start, end


def test_messages_hold_the_run_s_values_at_the_rig_s_time(mpc_run):
    result, _folder, _channels, messages, metadata = mpc_run
    log = result.log
    t = log["t_s"]
    expected_ns = np.round((t - t[0]) * 1e9).astype(np.int64)
    for topic, (x, y, z) in {
        "/capsule/true": ("capsule_x_m", "capsule_y_m", "capsule_z_m"),
        "/epm/pose": ("epm_x_m", "epm_y_m", "epm_z_m"),
    }.items():
        got = messages[topic]
        np.testing.assert_array_equal([ns for ns, _ in got], expected_ns)
        pos = np.array([[m.pose.position.x, m.pose.position.y, m.pose.position.z] for _, m in got])
        np.testing.assert_array_equal(pos, np.column_stack([log[x], log[y], log[z]]), err_msg=topic)
        assert all(m.frame_id == "world" for _, m in got)
    ref = np.array([[m.pose.position.x, m.pose.position.y] for _, m in messages["/reference/pose"]])
    np.testing.assert_array_equal(ref, np.column_stack([log["ref_x_m"], log["ref_y_m"]]))
    valid = np.isfinite(log["meas_x_m"])
    meas = np.array([[m.pose.position.x, m.pose.position.y] for _, m in messages["/capsule/measured"]])
    np.testing.assert_array_equal(meas, np.column_stack([log["meas_x_m"], log["meas_y_m"]])[valid])
    tracking = [m for _, m in messages["/run/tracking"]]
    err = np.hypot(log["capsule_x_m"] - log["ref_x_m"], log["capsule_y_m"] - log["ref_y_m"]) * 1e3
    np.testing.assert_allclose([m["error_mm"] for m in tracking], err, rtol=1e-12)
    command = [m for _, m in messages["/run/command"]]
    for axis in ("x", "y", "z"):
        np.testing.assert_array_equal([m[f"cmd_v{axis}_mps"] for m in command], log[f"cmd_v{axis}_mps"])
    assert [m["solver_status"] for m in command] == log["solver_status"].tolist()
    (record,) = [m for m in metadata if m.name == "capsule_mpc.run"]
    assert record.metadata["controller"] == "mpc" and record.metadata["config"] == "test"
    assert float(record.metadata["time_zero_rig_s"]) == t[0]


def test_the_prediction_is_the_controller_s_and_the_events_tell_the_run(mpc_run):
    result, _folder, _channels, messages, _metadata = mpc_run
    for (_ns, update), predicted in zip(messages["/mpc/prediction"], result.predictions):
        if predicted is None:
            assert [d.id for d in update.deletions] == ["prediction"] and not update.entities
        else:
            (line,) = update.entities[0].lines
            np.testing.assert_array_equal([[p.x, p.y] for p in line.points], predicted)
    assert any(p is not None for p in result.predictions)
    events = [m for _, m in messages["/run/events"]]
    assert events[0].message.startswith("run started: controller mpc, seed 1")
    assert "path started" in events[1].message
    assert events[-1].message.startswith(f"run ended: {result.metrics['outcome']}")
    # One event per change of the log's phase column, naming both phases.
    phase = result.log["phase"]
    changes = [f"phase: {a} -> {b}" for a, b in itertools.pairwise(phase) if a != b]
    assert changes and [e.message.split(" (")[0] for e in events if e.message.startswith("phase:")] == changes


def _matrix(tf) -> np.ndarray:
    """The 4x4 matrix of a decoded FrameTransform."""
    x, y, z, w = tf.rotation.x, tf.rotation.y, tf.rotation.z, tf.rotation.w
    rot = np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
            [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
            [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
        ]
    )
    m = np.eye(4)
    m[:3, :3], m[:3, 3] = rot, [tf.translation.x, tf.translation.y, tf.translation.z]
    return m


def test_the_arm_s_frames_put_its_flange_where_its_kinematics_do(mpc_run):
    # the chain world -> ... -> ur5/tool0 from /tf_static and /tf, then the EPM mount, lands on the
    # forward kinematics of the frame's joint states: the drawn arm is the arm that ran
    from capsule_mpc.arm import ArmKinematics

    result, _folder, _channels, messages, _metadata = mpc_run
    kin = ArmKinematics(result.scenario.arm)
    ((_, static),) = messages["/tf_static"]
    edges = {tf.child_frame_id: tf for tf in static.transforms}
    k = len(messages["/tf"]) // 2
    (_, moving), (_, joints) = messages["/tf"][k], messages["/arm/joint_states"][k]
    edges.update({tf.child_frame_id: tf for tf in moving.transforms})
    assert {tf.child_frame_id for tf in moving.transforms} >= {"capsule", "epm"}
    frame, chain = "ur5/tool0", np.eye(4)
    while frame != "world":
        chain = _matrix(edges[frame]) @ chain
        frame = edges[frame].parent_frame_id
    q = np.array([j.position for j in joints.joints])
    assert [j.name for j in joints.joints] == list(kin.joint_names)
    mount = np.eye(4)
    mount[:3, 3] = result.scenario.arm.mount_xyz_m
    np.testing.assert_allclose((chain @ mount)[:3, 3], kin.epm_position(q), atol=1e-9)


def test_export_of_the_run_folder_gives_the_same_channels_and_values(mpc_run, tmp_path):
    result, folder, channels, messages, _metadata = mpc_run
    out = tmp_path / "export.mcap"
    assert main(["log", "export", str(folder), "--format", "mcap", "--out", str(out)]) == 0
    exported, got, _ = read_mcap(out)
    # the run folder holds no estimate: every other channel, with as many messages
    assert set(exported) == set(channels) - {"/capsule/estimate"}
    for name in PER_FRAME + ONCE + ("/capsule/measured",):
        assert exported[name]["count"] == channels[name]["count"], name
    for topic in ("/capsule/true", "/epm/pose", "/reference/pose", "/capsule/measured"):
        assert [(ns, m.pose.position.x, m.pose.position.y) for ns, m in got[topic]] == [
            (ns, m.pose.position.x, m.pose.position.y) for ns, m in messages[topic]
        ], topic
    assert [m for _, m in got["/run/tracking"]] == [m for _, m in messages["/run/tracking"]]
    # the arm's joints at each frame of the motion: the tick the live run had reached
    moving = result.log["t_s"] >= 0
    live_q = np.array([[j.position for j in m.joints] for _, m in messages["/arm/joint_states"]])[moving]
    export_q = np.array([[j.position for j in m.joints] for _, m in got["/arm/joint_states"]])[moving]
    np.testing.assert_allclose(export_q, live_q, atol=1e-9)
    assert [m.message for _, m in got["/run/events"]][-1] == [m.message for _, m in messages["/run/events"]][
        -1
    ]


def _copy_run(folder: Path, dest: Path) -> Path:
    shutil.copytree(folder, dest, ignore=shutil.ignore_patterns("*.mcap", "*.png"))
    return dest


@pytest.mark.parametrize(
    ("case", "named"),
    [
        ("no folder", "RUN_DIR"),
        ("no log", "log.csv"),
        ("bad log", "log.csv"),
        ("bad summary", "run.json"),
        ("bad config", "config.yaml"),
        ("bad joints", "joint_trajectory.csv"),
        ("bad predictions", "predictions.npz"),
        ("out is a folder", "--out"),
    ],
)
def test_bad_run_folders_exit_2_naming_the_file(mpc_run, tmp_path, capsys, case, named):
    _result, folder, *_ = mpc_run
    run = _copy_run(folder, tmp_path / "run")
    argv = ["log", "export", str(run)]
    if case == "no folder":
        argv[2] = str(tmp_path / "nowhere")
    elif case == "no log":
        (run / "log.csv").unlink()
    elif case == "bad log":
        (run / "log.csv").write_text("t_s,capsule_x_m\n0.0,1.0\n", encoding="utf-8")
    elif case == "bad summary":
        (run / "run.json").write_text("{not json", encoding="utf-8")
    elif case == "bad config":
        (run / "config.yaml").write_text("plate: {epm_height_m: -1}\n", encoding="utf-8")
    elif case == "bad joints":
        (run / "joint_trajectory.csv").write_text("t_s,q1\nx,y\n", encoding="utf-8")
    elif case == "bad predictions":
        np.savez(run / "predictions.npz", t_s=np.zeros(2), capsule_xy_m=np.zeros((2, 3, 2)))
    else:
        argv += ["--out", str(tmp_path)]
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert named in err, err
    assert not list(tmp_path.rglob("*.mcap")) and not list(tmp_path.rglob(".*.tmp*"))


def test_a_run_that_raises_leaves_no_file(scenario, tmp_path):
    class Boom(Exception):
        pass

    def explode(loop, frame):
        raise Boom

    mcap = tmp_path / "run.mcap"
    tel = Telemetry(mcap)
    tel.after_controller = explode  # type: ignore[method-assign]
    with pytest.raises(Boom), tel:
        ClosedLoop(scenario, "follow", CORNER, seed=0).run([tel])
    assert list(tmp_path.iterdir()) == []


def test_the_layout_in_docs_is_the_generated_one_and_names_real_topics():
    text = (REPO / "docs" / "foxglove_layout.json").read_text(encoding="utf-8")
    assert text == layout_json()
    layout = json.loads(text)
    names = {t.name for t in TOPICS}
    for panel, config in layout["configById"].items():
        for path in config.get("paths", []):
            assert path["value"].split(".")[0] in names, (panel, path)
        for topic in config.get("topics", {}):
            assert topic in names, (panel, topic)
    assert layout["configById"]["RosOut!events"]["topicToRender"] == "/run/events"
    assert not math.isnan(layout["layout"]["splitPercentage"])
