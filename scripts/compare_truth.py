"""Print a calibration result next to a reference (e.g. the simulator's truth.yaml).

Usage: python scripts/compare_truth.py calib.yaml truth.yaml
"""

import argparse

from mocap_calib.io.yaml_io import load_result
from mocap_calib.report.compare import compare, format_rows


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("result", help="calibration YAML (calibrate --out)")
    parser.add_argument("truth", help="reference YAML, e.g. the simulator's truth.yaml")
    args = parser.parse_args()
    result, truth = load_result(args.result), load_result(args.truth)
    print(f"\nestimate vs truth ({args.truth}); |err|/sigma is the largest per-axis ratio")
    print(format_rows(compare(result, truth)))


if __name__ == "__main__":
    main()
