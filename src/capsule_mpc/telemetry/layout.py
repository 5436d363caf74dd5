"""The Foxglove layout of the telemetry (``docs/foxglove_layout.json``): a 3D panel of the rig, plots
of the tracking error, the commands and the positions, and the run's events.

The panels' settings are written with :mod:`foxglove.layouts` and arranged in the layout file
format Foxglove imports ("Import from file..." in the layout menu).
"""

from __future__ import annotations

import json
from typing import Any

import foxglove.layouts as fl

from .topics import (
    COMMAND,
    EPM_POSE,
    ESTIMATE,
    EVENTS,
    FRAME_WORLD,
    MEASURED,
    PREDICTION,
    REFERENCE,
    RIG_SCENE,
    ROBOT_DESCRIPTION,
    TRACKING,
    TRUE_CAPSULE,
)

__all__ = ["foxglove_layout", "layout_json"]

#: Arrow size of a pose (length, head width, head height), m.
_ARROW_M = (0.015, 0.003, 0.003)


def _dict(model: fl._BaseModel) -> dict[str, Any]:
    """A :mod:`foxglove.layouts` object as the plain dict the layout file holds."""
    return dict(json.loads(model.to_json()))


def _three_d() -> dict[str, Any]:
    def arrow(color: str) -> fl.BaseRendererPoseTopicSettings:
        return fl.BaseRendererPoseTopicSettings(visible=True, type="arrow", arrow_scale=_ARROW_M, color=color)

    config = fl.ThreeDeeConfig(
        camera_state=fl.ThreeDeeCameraState(
            distance=1.1,
            perspective=True,
            phi=55.0,
            theta_offset=35.0,
            target=(0.0, -0.15, 0.1),
            target_offset=(0.0, 0.0, 0.0),
            target_orientation=(0.0, 0.0, 0.0, 1.0),
            fovy=45.0,
            near=0.01,
            far=50.0,
        ),
        follow_tf=FRAME_WORLD,
        fixed_frame=FRAME_WORLD,
        follow_mode="follow-none",
        scene=fl.BaseRendererSceneSettings(
            transforms=fl.BaseRendererTransforms(visible=False, show_label=False, axis_size=0.03)
        ),
        topics={
            RIG_SCENE.name: fl.BaseRendererSceneUpdateTopicSettings(visible=True),
            PREDICTION.name: fl.BaseRendererSceneUpdateTopicSettings(visible=True),
            MEASURED.name: arrow("#e53935"),
            ESTIMATE.name: arrow("#43a047"),
            REFERENCE.name: arrow("#1e88e5"),
            TRUE_CAPSULE.name: fl.BaseRendererPoseTopicSettings(visible=False),
            EPM_POSE.name: fl.BaseRendererPoseTopicSettings(visible=False),
            ROBOT_DESCRIPTION.name: fl.BaseRendererUrdfTopicSettings(visible=False),  # drawn by /rig/scene
        },
    )
    return {**_dict(config), "foxglovePanelTitle": "Rig"}


def _plot(title: str, series: list[tuple[str, str]], y_label: str) -> dict[str, Any]:
    config = fl.PlotConfig(
        paths=[
            fl.PlotSeries(value=value, label=label, enabled=True, timestamp_method="receiveTime")
            for value, label in series
        ],
        show_legend=True,
        legend_display="floating",
        show_x_axis_labels=True,
        show_y_axis_labels=True,
        is_synced=True,
        x_axis_val="timestamp",
        y_axis_label=y_label,
    )
    return {**_dict(config), "foxglovePanelTitle": title}


def _events() -> dict[str, Any]:
    config = fl.LogConfig(topic_to_render=EVENTS.name, min_log_level=1, show_level=True, show_name=False)
    return {**_dict(config), "foxglovePanelTitle": "Run events"}


def foxglove_layout() -> dict[str, Any]:
    """The layout: the 3D panel on the left; on the right the tracking error, the EPM velocity
    commands, the capsule's and the reference's positions, and the run's events."""
    t, c = TRACKING.name, COMMAND.name
    panels = {
        "3D!rig": _three_d(),
        "Plot!error": _plot("Tracking error", [(f"{t}.error_mm", "|capsule - reference| (mm)")], "mm"),
        "Plot!command": _plot(
            "EPM velocity command",
            [(f"{c}.cmd_vx_mps", "vx"), (f"{c}.cmd_vy_mps", "vy"), (f"{c}.cmd_vz_mps", "vz")],
            "m/s",
        ),
        "Plot!position": _plot(
            "Capsule and reference",
            [
                (f"{t}.capsule_x_m", "capsule x"),
                (f"{t}.ref_x_m", "reference x"),
                (f"{t}.capsule_y_m", "capsule y"),
                (f"{t}.ref_y_m", "reference y"),
            ],
            "m",
        ),
        "RosOut!events": _events(),
    }
    right = {
        "first": {"first": "Plot!error", "second": "Plot!command", "direction": "column"},
        "second": {
            "first": "Plot!position",
            "second": "RosOut!events",
            "direction": "column",
            "splitPercentage": 65,
        },
        "direction": "column",
    }
    return {
        "configById": panels,
        "globalVariables": {},
        "userNodes": {},
        "playbackConfig": {"speed": 1},
        "layout": {"first": "3D!rig", "second": right, "direction": "row", "splitPercentage": 55},
    }


def layout_json() -> str:
    """:func:`foxglove_layout` as the text of ``docs/foxglove_layout.json``."""
    return json.dumps(foxglove_layout(), indent=2) + "\n"
