"""Pre-flight configuration rules (agent.flight.preflight)."""

from __future__ import annotations

import pytest

from agent.flight.preflight import (
    PARAMETER_TABLE,
    preflight_problems,
    problem_line,
    readme_table,
)

ARDUPILOT_OK = {
    "VISO_TYPE": 1.0, "AHRS_EKF_TYPE": 3.0, "EK3_SRC1_POSXY": 6.0, "EK3_SRC1_POSZ": 6.0,
    "EK3_SRC1_YAW": 6.0, "EK3_SRC1_VELXY": 6.0, "EK3_SRC1_VELZ": 0.0, "GUID_OPTIONS": 8.0,
    "ARMING_CHECK": 1.0, "MOT_THST_HOVER": 0.35,
}
# A freshly flashed ArduCopter (the defaults) with a yaw from the compass.
ARDUPILOT_DEFAULTS = {
    "VISO_TYPE": 0.0, "AHRS_EKF_TYPE": 3.0, "EK3_SRC1_POSXY": 3.0, "EK3_SRC1_POSZ": 1.0,
    "EK3_SRC1_YAW": 1.0, "EK3_SRC1_VELXY": 3.0, "EK3_SRC1_VELZ": 3.0, "GUID_OPTIONS": 0.0,
    "ARMING_CHECK": 0.0,
}
PX4_OK = {"EKF2_EV_CTRL": 11.0, "EKF2_HGT_REF": 3.0, "COM_OF_LOSS_T": 0.5,
          "COM_OBL_RC_ACT": 4.0, "MPC_THR_HOVER": 0.4}
PX4_WRONG = {"EKF2_EV_CTRL": 9.0, "EKF2_HGT_REF": 1.0, "COM_OF_LOSS_T": 5.0,
             "COM_OBL_RC_ACT": 3.0, "COM_OBL_ACT": 2.0}


def test_correct_configurations_have_no_problems() -> None:
    assert preflight_problems("ardupilot", ARDUPILOT_OK) == []
    assert preflight_problems("px4", PX4_OK) == []
    assert preflight_problems("px4", {**PX4_OK, "EKF2_EV_CTRL": 15.0, "COM_OBL_ACT": 0.0}) == []


def test_ardupilot_defaults_give_exactly_the_expected_problems() -> None:
    problems = preflight_problems("ardupilot", ARDUPILOT_DEFAULTS)
    got = [(p.param, p.found, p.fatal) for p in problems]
    assert got == [
        ("VISO_TYPE", 0.0, True),
        ("EK3_SRC1_POSXY", 3.0, True),
        ("EK3_SRC1_POSZ", 1.0, True),
        ("EK3_SRC1_YAW", 1.0, True),
        ("EK3_SRC1_VELXY", 3.0, True),
        ("EK3_SRC1_VELZ", 3.0, True),
        ("GUID_OPTIONS", 0.0, False),  # the driver sets it: reported, not fatal
        ("ARMING_CHECK", 0.0, False),
    ]
    viso = problems[0]
    assert "VISO_TYPE 1" in viso.fix and "non-zero" in viso.required
    for p in problems:
        line = problem_line(p)
        assert "\n" not in line and p.param in line and p.fix in line


def test_px4_wrong_configuration_gives_exactly_the_expected_problems() -> None:
    got = [(p.param, p.found) for p in preflight_problems("px4", PX4_WRONG)]
    assert got == [("EKF2_EV_CTRL", 9.0), ("EKF2_HGT_REF", 1.0), ("COM_OF_LOSS_T", 5.0),
                   ("COM_OBL_RC_ACT", 3.0), ("COM_OBL_ACT", 2.0)]


@pytest.mark.parametrize(("param", "value", "bad"), [
    ("EKF2_EV_CTRL", 3.0, True),  # positions without yaw
    ("EKF2_EV_CTRL", 15.0, False),
    ("COM_OF_LOSS_T", 0.0, True),
    ("COM_OF_LOSS_T", 1.0, False),
    ("COM_OF_LOSS_T", 1.01, True),
    ("COM_OBL_RC_ACT", 6.0, True),  # Terminate
    ("COM_OBL_RC_ACT", 7.0, True),  # Disarm / Lockdown
    ("COM_OBL_RC_ACT", -1.0, True),  # Disabled
    ("COM_OBL_RC_ACT", 5.0, False),  # Hold
])
def test_px4_single_rules(param: str, value: float, bad: bool) -> None:
    problems = preflight_problems("px4", {**PX4_OK, param: value})
    assert [p.param for p in problems] == ([param] if bad else [])


def test_missing_parameters_are_problems_unless_optional() -> None:
    problems = preflight_problems("px4", {})
    assert [p.param for p in problems] == ["EKF2_EV_CTRL", "EKF2_HGT_REF", "COM_OF_LOSS_T",
                                           "COM_OBL_RC_ACT"]
    assert all(p.found is None and "not read" in p.fix for p in problems)
    no_arming = {k: v for k, v in ARDUPILOT_OK.items() if k != "ARMING_CHECK"}
    assert preflight_problems("ardupilot", no_arming) == []
    assert [p.param for p in preflight_problems("ardupilot", {**ARDUPILOT_OK,
                                                               "VISO_TYPE": float("nan")})] \
        == ["VISO_TYPE"]
    with pytest.raises(ValueError):
        preflight_problems("inav", {})


def test_guid_options_bit_among_other_bits() -> None:
    assert preflight_problems("ardupilot", {**ARDUPILOT_OK, "GUID_OPTIONS": 8 + 4 + 1}) == []
    assert [p.param for p in preflight_problems("ardupilot", {**ARDUPILOT_OK,
                                                               "GUID_OPTIONS": 7.0})] \
        == ["GUID_OPTIONS"]


def test_readme_table_lists_every_rule() -> None:
    table = readme_table().splitlines()
    assert table[0].startswith("| Parameter |") and len(table) == 2 + len(PARAMETER_TABLE)
    assert all(f"`{r.param}`" in table[i + 2] for i, r in enumerate(PARAMETER_TABLE))
