"""Input and output at the edges: the only layer that reads or writes files.

    yaml_rules.py  the rules every YAML text is read under (size, depth, expanded size, no key twice)
    fields.py      the field-reader framework: one line "FILE: FIELD: reason" per bad value
    scenario.py    scenario YAML → validated, frozen `Model` (one reader per section)
    overrides.py   `--set PATH=VALUE` overrides of a scenario's data, before validation
    robots.py      arms from URDF and MJCF robot files (MuJoCo's compiler), the bundled robots
    torque_csv.py  torque tables as CSV
    mcap_codec.py  MCAP files of JSON series and topics with their JSON Schemas, read back bit for bit
    foxglove.py    the Foxglove 3D view: published schemas, /tf frames and /scene boxes of a model
    log.py         run logs: a run (and its twin) as series, metadata records, written and read
    urdf.py        the scene as a URDF (each arm an open chain, the object fixed to the carrier)
    ros2_msgs.py   the ROS 2 message definitions a bag uses, as MCAP ros2msg schemas, and their type hashes
    ros2.py        a run as a ROS 2 bag: a rosbag2 folder of standard CDR messages (joint states, TF, …)
    atomic.py      atomic outputs: each file, and each command's files as one set
    processes.py   helper processes that end with the command however it ends (figure workers, compiles)
"""
