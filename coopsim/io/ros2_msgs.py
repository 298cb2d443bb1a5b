"""The ROS 2 message types a coopsim bag uses: their .msg definitions (ROS 2's, comments left out), the
concatenated form an MCAP `ros2msg` schema holds (the type, then each dependency after a line of 80 '='
and `MSG: pkg/Type`), and each type's RIHS01 type-description hash (what ROS 2 from Jazzy on records
beside a topic; tests/io/test_ros2.py checks the definitions and hashes against rosbags' type store).
"""

from __future__ import annotations

import re

DEFINITIONS: dict[str, str] = {
    "builtin_interfaces/Time": "int32 sec\nuint32 nanosec\n",
    "std_msgs/Header": "builtin_interfaces/Time stamp\nstring frame_id\n",
    "std_msgs/String": "string data\n",
    "geometry_msgs/Vector3": "float64 x\nfloat64 y\nfloat64 z\n",
    "geometry_msgs/Point": "float64 x\nfloat64 y\nfloat64 z\n",
    "geometry_msgs/Quaternion": "float64 x 0\nfloat64 y 0\nfloat64 z 0\nfloat64 w 1\n",
    "geometry_msgs/Pose": "geometry_msgs/Point position\ngeometry_msgs/Quaternion orientation\n",
    "geometry_msgs/PoseStamped": "std_msgs/Header header\ngeometry_msgs/Pose pose\n",
    "geometry_msgs/Twist": "geometry_msgs/Vector3 linear\ngeometry_msgs/Vector3 angular\n",
    "geometry_msgs/TwistStamped": "std_msgs/Header header\ngeometry_msgs/Twist twist\n",
    "geometry_msgs/Wrench": "geometry_msgs/Vector3 force\ngeometry_msgs/Vector3 torque\n",
    "geometry_msgs/WrenchStamped": "std_msgs/Header header\ngeometry_msgs/Wrench wrench\n",
    "geometry_msgs/Transform": "geometry_msgs/Vector3 translation\ngeometry_msgs/Quaternion rotation\n",
    "geometry_msgs/TransformStamped": "std_msgs/Header header\nstring child_frame_id\n"
                                      "geometry_msgs/Transform transform\n",
    "tf2_msgs/TFMessage": "geometry_msgs/TransformStamped[] transforms\n",
    "sensor_msgs/JointState": "std_msgs/Header header\nstring[] name\nfloat64[] position\nfloat64[] velocity\n"
                              "float64[] effort\n",
    "diagnostic_msgs/KeyValue": "string key\nstring value\n",
    "diagnostic_msgs/DiagnosticStatus": "byte OK=0\nbyte WARN=1\nbyte ERROR=2\nbyte STALE=3\nbyte level\nstring name\n"
                                        "string message\nstring hardware_id\ndiagnostic_msgs/KeyValue[] values\n",
    "diagnostic_msgs/DiagnosticArray": "std_msgs/Header header\ndiagnostic_msgs/DiagnosticStatus[] status\n",
    "rosgraph_msgs/Clock": "builtin_interfaces/Time clock\n",
}

# RIHS01 hashes of the top-level types (ROS 2's type description hashes; the same in Humble's and Jazzy's
# definitions of these types)
TYPE_HASHES: dict[str, str] = {
    "sensor_msgs/msg/JointState": "RIHS01_a13ee3a330e346c9d87b5aa18d24e11690752bd33a0350f11c5882bc9179260e",
    "tf2_msgs/msg/TFMessage": "RIHS01_e369d0f05a23ae52508854b66f6aa0437f3449d652e8cbf22d5abe85d020f087",
    "geometry_msgs/msg/PoseStamped": "RIHS01_10f3786d7d40fd2b54367835614bff85d4ad3b5dab62bf8bca0cc232d73b4cd8",
    "geometry_msgs/msg/TwistStamped": "RIHS01_5f0fcd4f81d5d06ad9b4c4c63e3ea51b82d6ae4d0558f1d475229b1121db6f64",
    "geometry_msgs/msg/WrenchStamped": "RIHS01_8dc3deaf06b2ab281f9f9a742a8961c328ca7cec16e3fd6586d3a5c83fa78f77",
    "std_msgs/msg/String": "RIHS01_df668c740482bbd48fb39d76a70dfd4bd59db1288021743503259e948f6b1a18",
    "diagnostic_msgs/msg/DiagnosticArray": "RIHS01_5a8a36efb05fb25070fa0fb3810290c0e6cd4862b54a8fb975a1ee8dc55a333e",
    "rosgraph_msgs/msg/Clock": "RIHS01_692f7a66e93a3c83e71765d033b60349ba68023a8c689a79e48078bcb5c58564",
}

_SEPARATOR = "=" * 80


def short_name(type_name: str) -> str:
    """'pkg/msg/Type' → 'pkg/Type' (the form of DEFINITIONS' keys and of `MSG:` lines).

    Args:
        type_name: a ROS 2 message type name, with or without '/msg/'.

    Returns:
        str: the name without '/msg/'.
    """
    return type_name.replace("/msg/", "/")


def dependencies(type_name: str) -> list[str]:
    """The message types a type's fields use, depth first in field order, each once (the type itself not).

    Args:
        type_name: a type of DEFINITIONS, 'pkg/msg/Type' or 'pkg/Type'.

    Returns:
        list[str]: 'pkg/Type' names.
    """
    out: list[str] = []

    def visit(name: str) -> None:
        for line in DEFINITIONS[name].splitlines():
            field_type = re.sub(r"\[.*\]$", "", line.split()[0])
            if "/" in field_type and field_type not in out:
                out.append(field_type)
                visit(field_type)

    visit(short_name(type_name))
    return out


def schema_text(type_name: str) -> str:
    """The MCAP `ros2msg` schema of a type: its definition and every dependency's, concatenated.

    Args:
        type_name: a type of DEFINITIONS, 'pkg/msg/Type'.

    Returns:
        str: the definition, then for each dependency a line of 80 '=', 'MSG: pkg/Type' and its definition.
    """
    parts = [DEFINITIONS[short_name(type_name)]]
    parts += [f"{_SEPARATOR}\nMSG: {dep}\n{DEFINITIONS[dep]}" for dep in dependencies(type_name)]
    return "".join(parts)
