"""A parameter change without a node: the values refused on their own, and the config's changes."""

from __future__ import annotations

from array import array

from rclpy.parameter import Parameter

from roadbev_ros.node_params import param_changes, report_bad_values


def test_each_value_refused_on_its_own_is_reported_and_the_parameters_go_on_unchanged() -> None:
    reported: list[tuple[str, str]] = []
    parameters = [Parameter("sync_slop_s", value=5.0), Parameter("sync_queue_size", value=20),
                  Parameter("image_transport", value="jpeg")]
    assert report_bad_values(parameters, lambda kind, reason: reported.append((kind, reason))) is parameters
    assert reported == [("parameter", "rejected: sync_slop_s = 5.0 is above its maximum 1.0"),
                        ("parameter", "rejected: image_transport must be one of raw, compressed; got 'jpeg'")]


def test_param_changes_gives_the_first_refused_value_and_the_config_changes() -> None:
    error, changes = param_changes([Parameter("sync_slop_s", value=0.03), Parameter("use_sim_time", value=True),
                                    Parameter("vehicle.camera_position_m", value=array("d", [1.6, 0.0, 1.1]))])
    assert error is None
    assert changes == {"sync_slop_s": 0.03, "vehicle.camera_position_m": [1.6, 0.0, 1.1]}  # use_sim_time: rclpy's
    error, changes = param_changes([Parameter("sync_queue_size", value=20), Parameter("sync_slop_s", value=5.0),
                                    Parameter("image_transport", value="jpeg")])
    assert error == "sync_slop_s = 5.0 is above its maximum 1.0"
    assert changes == {"sync_queue_size": 20, "sync_slop_s": 5.0, "image_transport": "jpeg"}
    assert param_changes([Parameter("use_sim_time", value=True)]) == (None, {})
