"""Pre-flight rules on the autopilot's configuration: given the flavour (its name; the rules of
its ``param_family`` apply, 'ardupilot' or 'px4') and the parameters read over the MAVLink
parameter protocol (name → value), list what is wrong for indoor flight on forwarded motion
capture with SET_ATTITUDE_TARGET.

Values are compared as integers where the parameter is an integer. PX4 sends INT32 values
byte-wise in PARAM_VALUE.param_value: the caller must decode them by param_type before
building the dict (a 3 read as a float otherwise looks like 4.2e-45).

Facts behind each rule (checked in the autopilots' own sources):

* ArduPilot libraries/AP_VisualOdom/AP_VisualOdom.cpp: VISO_TYPE 0:None, 1:MAVLink,
  2:IntelT265, 3:VOXL, reboot required; handle_pose_estimate() returns at once unless
  enabled, so forwarded VISION_POSITION_ESTIMATE / ODOMETRY is discarded with VISO_TYPE 0.
* ArduPilot libraries/AP_NavEKF/AP_NavEKF_Source.cpp: EK3_SRC1_POSXY / POSZ / VELXY / VELZ
  value 6 = ExternalNav (3 = GPS; defaults POSXY 3, VELXY 3, POSZ 1 Baro, VELZ 3);
  EK3_SRC1_YAW 0:None, 1:Compass, 2:GPS, 3:GPS with Compass Fallback, 6:ExternalNav, 8:GSF
  (releases before 4.1's ExternalNav yaw lack 6); pre_arm_check() fails with
  "EK3 sources require GPS" when a GPS source is set and no GPS is present.
* ArduPilot libraries/AP_AHRS/AP_AHRS.cpp: AHRS_EKF_TYPE 0:Disabled, 2:EKF2, 3:EKF3,
  11:ExternalAHRS; the EK3_SRC* parameters act only with EKF3.
* ArduCopter/Parameters.cpp: GUID_OPTIONS bit 3 "SetAttitudeTarget interprets Thrust As
  Thrust" (otherwise thrust is a climb-rate command); our driver sets it itself.
* ArduCopter/AP_Arming.cpp: with ARMING_CHECK 0 only the mandatory checks run.
* PX4 src/modules/ekf2/params_external_vision.yaml: EKF2_EV_CTRL bits 0 horizontal
  position, 1 vertical position, 2 3D velocity, 3 yaw (default 0).
* PX4 src/modules/ekf2 (ekf2_params.c): EKF2_HGT_REF 0 baro, 1 GPS (default), 2 range,
  3 vision; reboot required.
* PX4 src/modules/commander/commander_params.c: COM_OF_LOSS_T [s], the offboard-loss
  time-out (default 1.0 s in current releases, 0 in old ones); COM_OBL_RC_ACT 0 Position,
  1 Altitude, 2 Manual/Stabilized, 3 Return, 4 Land, 5 Hold, 6 Terminate, 7 Disarm
  (Lockdown in some releases), −1 Disabled; older firmware also has COM_OBL_ACT
  (0 Land, 1 Hold, 2 Return, 3 Terminate, 4 Lockdown).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

from agent.flight.flavours import flavour

EXTERNAL_NAV = 6  #: ArduPilot EK3_SRC* value for ExternalNav
EKF2_EV_NEEDED = 0b1011  #: PX4 EKF2_EV_CTRL bits: horizontal, vertical position and yaw
GUID_OPTIONS_REAL_THRUST = 8  #: ArduCopter GUID_OPTIONS bit 3


@dataclass(frozen=True)
class Rule:
    """One configuration rule: parameter, flavour (the ``param_family`` of the flavours it
    applies to), what is required (text), whether a value
    is acceptable (``integer`` parameters are rounded first), why (text), the one-line fix;
    ``fatal`` problems must stop the flight; ``optional`` rules apply only when the parameter
    exists; ``mocap`` rules only when the EKF is to fuse forwarded motion capture."""

    param: str
    flavour: str
    required: str
    accepts: Callable[[float], bool]
    why: str
    fix: str
    fatal: bool = True
    optional: bool = False
    integer: bool = True
    mocap: bool = False  #: only when flying on forwarded motion capture (``pose = "mocap"``)


@dataclass(frozen=True)
class Problem:
    """A rule broken: the parameter, the value found (None: not present), what is required,
    the one-line fix, and whether it must stop the flight."""

    param: str
    found: float | None
    required: str
    fix: str
    fatal: bool


def _ext(param: str) -> Rule:
    """ArduPilot EK3 primary source set to ExternalNav."""
    return Rule(param, "ardupilot", "6 (ExternalNav)", lambda v: v == EXTERNAL_NAV,
                "EKF3 must take this from the forwarded motion capture",
                f"set {param} 6 (ExternalNav) and reboot", mocap=True)


#: Every rule, in reporting order; also the source of the README table (:func:`readme_table`).
PARAMETER_TABLE: tuple[Rule, ...] = (
    Rule("VISO_TYPE", "ardupilot", "non-zero (1 MAVLink)", lambda v: v != 0,
         "with 0 ArduPilot discards forwarded VISION_POSITION_ESTIMATE / ODOMETRY",
         "set VISO_TYPE 1 (MAVLink) and reboot", mocap=True),
    Rule("AHRS_EKF_TYPE", "ardupilot", "3 (EKF3)", lambda v: v == 3,
         "the EK3_SRC* source selection only acts in EKF3", "set AHRS_EKF_TYPE 3 and reboot",
         mocap=True),
    _ext("EK3_SRC1_POSXY"),
    _ext("EK3_SRC1_POSZ"),
    _ext("EK3_SRC1_YAW"),
    Rule("EK3_SRC1_VELXY", "ardupilot", "0 (None) or 6 (ExternalNav)",
         lambda v: v in (0, EXTERNAL_NAV),
         "a GPS velocity source indoors fails pre-arm (EK3 sources require GPS)",
         "set EK3_SRC1_VELXY 6 when forwarding ODOMETRY, else 0", mocap=True),
    Rule("EK3_SRC1_VELZ", "ardupilot", "0 (None) or 6 (ExternalNav)",
         lambda v: v in (0, EXTERNAL_NAV),
         "a GPS velocity source indoors fails pre-arm (EK3 sources require GPS)",
         "set EK3_SRC1_VELZ 6 when forwarding ODOMETRY, else 0", mocap=True),
    Rule("GUID_OPTIONS", "ardupilot", "bit 3 set (value includes 8)",
         lambda v: bool(int(v) & GUID_OPTIONS_REAL_THRUST),
         "without it SET_ATTITUDE_TARGET thrust is a climb rate, not thrust",
         "let the driver set it (set_guid_options) or OR 8 into GUID_OPTIONS", fatal=False),
    Rule("ARMING_CHECK", "ardupilot", "non-zero (1 = all checks)", lambda v: v != 0,
         "0 runs only the mandatory pre-arm checks", "set ARMING_CHECK 1", fatal=False,
         optional=True),
    Rule("EKF2_EV_CTRL", "px4", "bits 0, 1 and 3 set (value & 11 == 11)",
         lambda v: int(v) & EKF2_EV_NEEDED == EKF2_EV_NEEDED,
         "EKF2 fuses vision horizontal and vertical position and yaw only with these bits",
         "set EKF2_EV_CTRL 11 (15 with ODOMETRY velocity)", mocap=True),
    Rule("EKF2_HGT_REF", "px4", "3 (Vision)", lambda v: v == 3,
         "height must follow the motion capture, not the barometer or GPS",
         "set EKF2_HGT_REF 3 and reboot", mocap=True),
    Rule("COM_OF_LOSS_T", "px4", "0.1 .. 1.0 s", lambda v: 0.1 <= v <= 1.0,
         "a longer time-out flies on a stale set-point; shorter trips on jitter",
         "set COM_OF_LOSS_T 0.5", integer=False),
    Rule("COM_OBL_RC_ACT", "px4", "0, 1, 2, 4 or 5 (4 Land recommended)",
         lambda v: v in (0, 1, 2, 4, 5),
         "Return climbs to RTL altitude indoors; Terminate/Disarm drop the vehicle",
         "set COM_OBL_RC_ACT 4 (Land)"),
    Rule("COM_OBL_ACT", "px4", "0 (Land) or 1 (Hold)", lambda v: v in (0, 1),
         "older firmware's offboard-loss action without RC: no Return or Terminate indoors",
         "set COM_OBL_ACT 0 (Land)", optional=True),
)


def _accepts(rule: Rule, value: float) -> bool:
    """Rule check on a parameter value (integers compared as integers)."""
    if not math.isfinite(value):
        return False
    return rule.accepts(float(round(value)) if rule.integer else value)


#: The fence rules (``viscover preflight --fence``, and before a flight with a fence):
#: ArduPilot AC_Fence (FENCE_ENABLE, FENCE_ACTION 0 = report only, FENCE_TYPE bits 1 max
#: altitude / 2 circle / 4 polygon / 8 min altitude); PX4 geofence_params (GF_ACTION 0 none,
#: 1 warning, 2 hold, 3 return, 4 terminate, 5 land).
FENCE_TABLE: tuple[Rule, ...] = (
    Rule("FENCE_ENABLE", "ardupilot", "1 (enabled)", lambda v: v == 1,
         "with 0 the uploaded fence is stored but never enforced", "set FENCE_ENABLE 1"),
    Rule("FENCE_ACTION", "ardupilot", "non-zero (1 RTL or land, 4 brake or land)",
         lambda v: v != 0, "0 only reports a breach: nothing stops the drone",
         "set FENCE_ACTION 4 (brake or land) or 1 (RTL or land)"),
    Rule("FENCE_TYPE", "ardupilot", "bits 1 and 4 (max altitude, polygon)",
         lambda v: int(v) & 5 == 5, "without bit 4 the uploaded polygon is not enforced",
         "let the driver set it when it uploads the fence, or OR 5 into FENCE_TYPE",
         fatal=False),
    Rule("GF_ACTION", "px4", "2 Hold, 3 Return, 4 Terminate or 5 Land",
         lambda v: v in (2, 3, 4, 5), "0 ignores a breach, 1 only warns",
         "set GF_ACTION 2 (Hold) or 5 (Land)"),
)


def _table_problems(table: tuple[Rule, ...], autopilot: str, params: dict[str, float],
                    pose: str) -> list[Problem]:
    family = flavour(autopilot).param_family  # ValueError (one line) for an unknown autopilot
    out = []
    for rule in table:
        if rule.flavour != family or (rule.mocap and pose != "mocap"):
            continue
        value = params.get(rule.param)
        if value is None:
            if not rule.optional:
                out.append(Problem(rule.param, None, rule.required,
                                   f"{rule.param} was not read (old firmware?): {rule.fix}",
                                   rule.fatal))
        elif not _accepts(rule, value):
            out.append(Problem(rule.param, value, rule.required, rule.fix, rule.fatal))
    return out


def preflight_problems(autopilot: str, params: dict[str, float],
                       pose: str = "mocap") -> list[Problem]:
    """Problems of the configuration ``params`` (name → value) for flavour ``autopilot`` (a
    flavour's name), in :data:`PARAMETER_TABLE` order; empty when all is well.
    ``pose`` "autopilot" (the vehicle flies on its own GNSS estimate) skips the rules that
    make its EKF fuse motion capture."""
    return _table_problems(PARAMETER_TABLE, autopilot, params, pose)


def fence_problems(autopilot: str, params: dict[str, float]) -> list[Problem]:
    """Problems of the fence configuration (:data:`FENCE_TABLE`) for flavour ``autopilot``."""
    return _table_problems(FENCE_TABLE, autopilot, params, "any")


def problem_line(p: Problem) -> str:
    """One human line: 'EK3_SRC1_YAW = 1, needs 6 (ExternalNav): set ... (fatal)'."""
    found = "missing" if p.found is None else f"{p.found:g}"
    return f"{p.param} = {found}, needs {p.required}: {p.fix}" + (" (fatal)" if p.fatal else "")


def readme_table() -> str:
    """The rules as a Markdown table for the README: parameter, flavour, required, why."""
    rows = ["| Parameter | Autopilot | Required | Why |", "| --- | --- | --- | --- |"]
    rows += [f"| `{r.param}` | {r.flavour} | {r.required} | {r.why} |" for r in PARAMETER_TABLE]
    return "\n".join(rows)
