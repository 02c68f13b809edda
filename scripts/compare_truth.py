"""Print a calibration result next to a reference (e.g. the simulator's truth.yaml).

Usage: python scripts/compare_truth.py calib.yaml truth.yaml
"""

import sys

from mocap_calib.io.yaml_io import load_result
from mocap_calib.workflows.compare import compare, format_rows


def main() -> None:
    result, truth = load_result(sys.argv[1]), load_result(sys.argv[2])
    print(f"\nestimate vs truth ({sys.argv[2]}); |err|/sigma is the largest per-axis ratio")
    print(format_rows(compare(result, truth)))


if __name__ == "__main__":
    main()
