"""The ROS 2 graph's documented numbers: a labelled reference, never a measurement.

ROS cannot run on this machine, so "better than a ROS graph" is argued against
what the two seeds (the source documents SPEC.md names as the requirements)
document about the system Lupin replaces. Every entry names its source. The
measured baseline of the same run is ``scservo_sdk`` (``bench/bus.py``).
"""

from __future__ import annotations

from typing import Any

LABEL = (
    "reference: documented in the seeds (arm-bringup.txt, teleop-runbook.txt) for the "
    "ROS 2 graph Lupin replaces; NOT measured here (ROS cannot run on this machine)"
)

REFERENCE: dict[str, dict[str, Any]] = {
    "arm_state_refresh_hz_per_joint": {
        "value": 8.3,
        "unit": "Hz",
        "source": "arm-bringup: 'arm states are read one joint per control cycle (~8 Hz per "
        "joint at the 50 Hz update rate) rather than six reads every cycle'",
    },
    "controller_update_rate_hz": {
        "value": 50,
        "unit": "Hz",
        "source": "arm-bringup: the mote_hardware controller_manager update rate",
    },
    "joint_states_publish_hz": {
        "value": 20.0,
        "unit": "Hz",
        "source": "arm-bringup run table: '/joint_states 6 arm joints at a steady 20.0 Hz'",
    },
    "joy_timeout_s": {
        "value": 0.3,
        "unit": "s",
        "source": "teleop-runbook twist_mux: /cmd_vel_joy priority 100, timeout 0.3 s (a "
        "silent pad hands over, or stops, only after this)",
    },
    "manual_and_auto_timeout_s": {
        "value": 0.5,
        "unit": "s",
        "source": "teleop-runbook twist_mux: /cmd_vel_manual and /cmd_vel_auto, 0.5 s",
    },
    "joy_autorepeat_hz": {
        "value": 20.0,
        "unit": "Hz",
        "source": "teleop-runbook: joy_node autorepeat_rate 20.0",
    },
    "arm_teleop_update_hz": {
        "value": 10.0,
        "unit": "Hz",
        "source": "teleop-runbook: arm_teleop update_rate_hz 10.0, 'matching the vendor "
        "controller_manager tick'",
    },
    "hmi_twist_hz": {
        "value": 10.0,
        "unit": "Hz",
        "source": "teleop-runbook: 'the web HMI sends roughly 10 Hz over rosbridge'",
    },
    "torque_engage_all_joints_s": {
        "value": 0.12,
        "unit": "s",
        "source": "arm-bringup: 'engages one joint per control cycle (~120 ms for all six)'",
    },
    "pad_bluetooth_interval_ms": {
        "value": [8.75, 11.25],
        "unit": "ms",
        "source": "teleop-runbook: BLE connection interval pinned to 8.75-11.25 ms, 'matching "
        "the pad's 100 Hz protocol'",
    },
    "processes": {
        "value": [
            "joy_node",
            "teleop_twist_joy",
            "twist_mux",
            "arm_teleop",
            "gripper_action_bridge",
            "joint trajectory controller (controller_manager)",
            "arm_preset_server",
            "auto_home",
            "rosbridge",
        ],
        "unit": "ROS nodes",
        "source": "SPEC.md and teleop-runbook: the graph Lupin replaces with one process",
    },
}


def reference() -> dict[str, Any]:
    return {"label": LABEL, "measured": False, "items": REFERENCE}
