"""Input and output at the edges: the only layer that reads or writes files.

    yaml_rules.py  the rules every YAML text is read under (size, depth, expanded size, no key twice)
    scenario.py    scenario YAML → validated, frozen `Model` (field readers, grasp and plane geometry)
    overrides.py   `--set PATH=VALUE` overrides of a scenario's data, before validation
    robots.py      arms from URDF and MJCF robot files (MuJoCo's compiler), the bundled robots
    torque_csv.py  torque tables as CSV
    log.py         MCAP run logs (JSON series, Foxglove schemas)
    atomic.py      atomic outputs: each file, and each command's files as one set
"""
