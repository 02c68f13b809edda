"""``python -m mocap_calib``: the command line, as ``mocap-calib``."""

from mocap_calib.cli.main import main

main()
