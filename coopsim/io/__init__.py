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
    atomic.py      atomic outputs: each file, and each command's files as one set
"""
