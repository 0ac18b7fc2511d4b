"""Profile loading: the packaged profiles load, and every mistake is refused by name."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import pytest
import yaml

from lupin.config import ConfigError, load_profile, packaged_profiles, read_yaml


@pytest.fixture()
def home(tmp_path: Path) -> Path:
    h = tmp_path / "home"
    h.mkdir()
    return h


def write_profile(tmp_path: Path, mutate: Any) -> str:
    """Copy the packaged so101 profile, let the test break it, return its path."""
    data = read_yaml(Path(__file__).parents[2] / "config/robots/so101.yaml")
    mutate(data)
    path = tmp_path / "robot.yaml"
    path.write_text(yaml.safe_dump(data))
    return str(path)


def refusal(tmp_path: Path, home: Path, mutate: Any) -> str:
    with pytest.raises(ConfigError) as info:
        load_profile(write_profile(tmp_path, mutate), home=home)
    return str(info.value)


def test_packaged_profiles_load(home: Path) -> None:
    assert {"so101", "mecanum"} <= set(packaged_profiles())
    so101 = load_profile(home=home)
    assert so101.name == "so101"
    assert [j.id for j in so101.arm.joints] == [1, 2, 3, 4, 5, 6]
    assert so101.base is not None and [w.id for w in so101.base.wheels] == [7, 9]
    assert so101.bus.baud == 1_000_000
    mec = load_profile("mecanum", home=home)
    assert mec.base is not None and mec.base.kind == "mecanum" and len(mec.base.wheels) == 4
    assert (
        set(mec.presets)
        == set(so101.presets)
        == {"home", "zero", "tuck", "pick", "place", "inspect"}
    )
    mux = so101.mux.topics
    assert (mux["joy"].priority, mux["joy"].timeout) == (100, 0.3)
    assert (mux["manual"].priority, mux["manual"].timeout) == (50, 0.5)
    assert (mux["auto"].priority, mux["auto"].timeout) == (10, 0.5)
    assert (mux["idle"].priority, mux["idle"].timeout, mux["idle"].sim_only) == (1, 1.0, True)


def test_unknown_profile_lists_known(home: Path) -> None:
    with pytest.raises(ConfigError, match=r"unknown profile 'so100'.*so101"):
        load_profile("so100", home=home)


def test_arm_id_equal_to_wheel_id_refused(tmp_path: Path, home: Path) -> None:
    def mutate(d: dict[str, Any]) -> None:
        d["arm"]["joints"][2]["id"] = 7

    msg = refusal(tmp_path, home, mutate)
    assert "base.wheels[0] (left).id: id 7 is already used by arm.joints[2] (elbow_flex)" in msg
    assert "robot.yaml" in msg


def test_duplicate_arm_ids_refused(tmp_path: Path, home: Path) -> None:
    def mutate(d: dict[str, Any]) -> None:
        d["arm"]["joints"][1]["id"] = 1

    msg = refusal(tmp_path, home, mutate)
    assert "arm.joints[1] (shoulder_lift).id: id 1 is already used" in msg


def test_duplicate_names_refused(tmp_path: Path, home: Path) -> None:
    def mutate(d: dict[str, Any]) -> None:
        d["arm"]["joints"][3]["name"] = "elbow_flex"

    msg = refusal(tmp_path, home, mutate)
    assert "duplicate name 'elbow_flex'" in msg


def test_zero_outside_limits_refused(tmp_path: Path, home: Path) -> None:
    def mutate(d: dict[str, Any]) -> None:
        d["arm"]["joints"][0]["zero"] = 4000

    msg = refusal(tmp_path, home, mutate)
    assert "arm.joints[0] (shoulder_pan).zero: 4000 is outside its limits [1024, 3072]" in msg


def test_min_not_below_max_refused(tmp_path: Path, home: Path) -> None:
    def mutate(d: dict[str, Any]) -> None:
        d["arm"]["joints"][4].update(min=3000, max=3000, zero=3000)

    msg = refusal(tmp_path, home, mutate)
    assert "arm.joints[4] (wrist_roll).min: min 3000 must be below max 3000" in msg


def test_unknown_key_refused(tmp_path: Path, home: Path) -> None:
    def mutate(d: dict[str, Any]) -> None:
        d["arm"]["joints"][1]["invret"] = True

    msg = refusal(tmp_path, home, mutate)
    assert "arm.joints[1] (shoulder_lift).invret: Extra inputs are not permitted" in msg


def test_wrong_type_refused(tmp_path: Path, home: Path) -> None:
    def mutate(d: dict[str, Any]) -> None:
        d["base"]["wheel_radius_m"] = "five"

    msg = refusal(tmp_path, home, mutate)
    assert "base.wheel_radius_m" in msg and "valid number" in msg


def test_out_of_range_counts_refused(tmp_path: Path, home: Path) -> None:
    def mutate(d: dict[str, Any]) -> None:
        d["arm"]["joints"][0]["max"] = 5000

    msg = refusal(tmp_path, home, mutate)
    assert "arm.joints[0] (shoulder_pan).max" in msg and "4095" in msg


def test_preset_may_not_move_gripper(tmp_path: Path, home: Path) -> None:
    def mutate(d: dict[str, Any]) -> None:
        d["presets"]["home"]["gripper"] = 0.5

    assert "presets never move the gripper" in refusal(tmp_path, home, mutate)


def test_preset_unknown_joint_refused(tmp_path: Path, home: Path) -> None:
    def mutate(d: dict[str, Any]) -> None:
        d["presets"]["pick"]["elbow"] = 0.5

    assert "presets.pick: 'elbow' is not an arm joint" in refusal(tmp_path, home, mutate)


def test_nan_refused(tmp_path: Path, home: Path) -> None:
    def mutate(d: dict[str, Any]) -> None:
        d["base"]["track_width_m"] = float("nan")

    assert "base.track_width_m" in refusal(tmp_path, home, mutate)


def test_invalid_yaml_names_file(tmp_path: Path, home: Path) -> None:
    bad = tmp_path / "bad.yaml"
    bad.write_text("arm: [unclosed\n")
    with pytest.raises(ConfigError, match=r"bad.yaml: not valid YAML"):
        load_profile(str(bad), home=home)


def test_top_level_not_a_mapping(tmp_path: Path, home: Path) -> None:
    bad = tmp_path / "list.yaml"
    bad.write_text("- 1\n- 2\n")
    with pytest.raises(ConfigError, match=r"list.yaml: expected a mapping"):
        load_profile(str(bad), home=home)


def test_overlay_replaces_zero_and_limits(home: Path) -> None:
    (home / "arm.yaml").write_text(
        yaml.safe_dump(
            {
                "joints": {
                    "elbow_flex": {
                        "zero": 2100,
                        "min": 900,
                        "max": 3300,
                        "measurement": {"swept": [850, 3350], "samples": 400},
                    }
                }
            }
        )
    )
    profile = load_profile(home=home)
    elbow = profile.joint("elbow_flex")
    assert (elbow.zero, elbow.min, elbow.max) == (2100, 900, 3300)
    # Untouched joints keep the packaged placeholders.
    assert profile.joint("shoulder_pan").zero == 2048
    # Deleting the overlay falls back to the defaults.
    (home / "arm.yaml").unlink()
    assert load_profile(home=home).joint("elbow_flex").zero == 2048


def test_overlay_is_validated_with_its_file_name(home: Path) -> None:
    (home / "arm.yaml").write_text(
        yaml.safe_dump({"joints": {"elbow_flex": {"zero": 100, "min": 900, "max": 3300}}})
    )
    with pytest.raises(ConfigError) as info:
        load_profile(home=home)
    msg = str(info.value)
    assert "arm.yaml" in msg and "elbow_flex).zero: 100 is outside its limits" in msg


def test_overlay_unknown_joint_refused(home: Path) -> None:
    (home / "arm.yaml").write_text(
        yaml.safe_dump({"joints": {"elbow": {"zero": 2048, "min": 900, "max": 3300}}})
    )
    with pytest.raises(ConfigError, match=r"arm.yaml: joints.elbow: not a joint"):
        load_profile(home=home)


def test_overlay_unknown_key_refused(home: Path) -> None:
    (home / "arm.yaml").write_text(
        yaml.safe_dump({"joints": {"elbow_flex": {"zero": 2048, "min": 9, "max": 3300, "x": 1}}})
    )
    with pytest.raises(ConfigError, match=r"joints.elbow_flex.x: Extra inputs"):
        load_profile(home=home)


def test_lupin_home_env(monkeypatch: pytest.MonkeyPatch, tmp_path: Path) -> None:
    monkeypatch.setenv("LUPIN_HOME", str(tmp_path))
    (tmp_path / "arm.yaml").write_text(
        yaml.safe_dump({"joints": {"gripper": {"zero": 2000, "min": 1950, "max": 2800}}})
    )
    assert load_profile().joint("gripper").zero == 2000


def test_site_config_merges_and_names_itself(tmp_path: Path, home: Path) -> None:
    site = tmp_path / "site.yaml"
    site.write_text("profile: mecanum\napi: {port: 9000, token: s3cret}\nbus: {port: /dev/x}\n")
    profile = load_profile(config_file=site, home=home)
    assert profile.name == "mecanum"
    assert (profile.api.port, profile.api.token, profile.bus.port) == (9000, "s3cret", "/dev/x")
    site.write_text("api: {port: 99999}\n")
    with pytest.raises(ConfigError, match=r"site.yaml: api.port"):
        load_profile(config_file=site, home=home)


def test_mux_estop_is_built_in(tmp_path: Path, home: Path) -> None:
    def mutate(d: dict[str, Any]) -> None:
        d["mux"]["locks"] = {"estop": {"topic": "e", "timeout": 0, "priority": 255}}

    assert "'estop' is built in" in refusal(tmp_path, home, mutate)


def test_base_wheel_count_checked(tmp_path: Path, home: Path) -> None:
    def mutate(d: dict[str, Any]) -> None:
        d["base"]["kind"] = "mecanum"
        d["base"]["wheelbase_m"] = 0.2

    assert "a mecanum base needs 4 wheels, got 2" in refusal(tmp_path, home, mutate)
