"""A command imports what it runs, not every other command's code (start-up time)."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest


def _modules_after(args: list[str]) -> set[str]:
    code = ("import sys\nfrom mocap_calib.cli.main import main\n"
            f"main({args!r})\nprint(' '.join(sorted(sys.modules)))\n")
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                          timeout=120)
    assert proc.returncode == 0, proc.stderr
    return set(proc.stdout.split())


def test_calibrate_does_not_import_the_other_commands() -> None:
    mods = _modules_after(["calibrate", "--help"])
    assert "mocap_calib.cli.commands.calibrate" in mods
    for other in ("simulate", "multipos", "batch", "groundtruth", "allan"):
        assert f"mocap_calib.cli.commands.{other}" not in mods, other
    assert "mocap_calib.sim.flight" not in mods  # the simulator, only `simulate` needs it


#: What a default ``calibrate`` run does not use, with what it costs at every start where it is
#: imported (resident memory, CPU; measured one import at a time on the development machine).
NOT_FOR_CALIBRATE = {
    "matplotlib": "16 MB, 0.2 s (the HTML report's figures)",
    "rerun": "~60 MB, 0.4 s (--rrd, view)",
    "scipy.stats": "with scipy.signal ~45 MB, 0.3 s",
    "scipy.signal": "the diagnosis' filters",
    "pandas": "64 MB", "pyarrow": "28 MB (only CSV files of 8 MiB and more, io/tables.py)",
    "dask": "batch --engine dask", "distributed": "batch --engine dask",
    "mocap_calib.sim": "simulate",
    "mocap_calib.core.diagnosis": "--model auto, diagnose",
    "mocap_calib.viz": "--rrd", "mocap_calib.export": "export",
    "mocap_calib.report.html": "--html",
    "mocap_calib.batch": "batch",
}


def test_a_calibration_imports_only_what_it_uses(tmp_path: Path) -> None:
    from mocap_calib.io.formats.euroc import write_euroc_imu, write_euroc_poses
    from mocap_calib.sim.flight import SimConfig, simulate_flight

    sim = simulate_flight(SimConfig(seed=2, duration=20.0, effects={"time_offset": [0.004]}))
    imu = write_euroc_imu(tmp_path / "imu.csv", sim.imu)
    mocap = write_euroc_poses(tmp_path / "mocap.csv", sim.mocap)
    mods = _modules_after(["calibrate", "--imu", str(imu), "--mocap", str(mocap), "--out",
                           str(tmp_path / "calib.yaml"), "--quiet"])
    assert "mocap_calib.core.pipeline.calibrate" in mods and (tmp_path / "calib.yaml").is_file()
    loaded = {name: why for name, why in NOT_FOR_CALIBRATE.items()
              if name in mods or any(m.startswith(name + ".") for m in mods)}
    assert not loaded, loaded


def test_the_top_level_help_lists_every_command() -> None:
    proc = subprocess.run([sys.executable, "-m", "mocap_calib", "--help"], capture_output=True,
                          text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr
    for name in ("simulate", "calibrate", "diagnose", "view", "multipos", "allan", "drift",
                 "export", "groundtruth", "batch"):
        assert name in proc.stdout, name


def test_reading_a_csv_loads_neither_pandas_nor_pyarrow(tmp_path: Path) -> None:
    """pandas alone is ~64 MB resident (pyarrow, which it pulls in, 65 MB more): the readers parse
    with numpy."""
    from mocap_calib.io.formats.euroc import write_euroc_imu
    from mocap_calib.sim.flight import SimConfig, simulate_flight

    csv = write_euroc_imu(tmp_path / "imu.csv", simulate_flight(SimConfig(duration=5.0)).imu)
    code = ("import sys\nfrom mocap_calib.io.formats.euroc import read_euroc_imu\n"
            f"n = len(read_euroc_imu({str(csv)!r}).t)\n"
            "print(n, 'pandas' in sys.modules, 'pyarrow' in sys.modules)\n")
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                          timeout=120)
    assert proc.returncode == 0, proc.stderr
    n, pandas, pyarrow = proc.stdout.split()
    assert int(n) > 900 and pandas == "False" and pyarrow == "False"


def test_the_command_line_starts_without_pyarrow() -> None:
    code = ("import sys\nimport mocap_calib.cli.main\nimport mocap_calib.io.formats.layout\n"
            "import mocap_calib.io.tables\n"
            "print('pyarrow' in sys.modules, 'pandas' in sys.modules)\n")
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                          timeout=120)
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.split() == ["False", "False"]


@pytest.mark.parametrize("cell,pyarrow", [("0.5", True), ("nan", False)])
def test_a_large_csv_loads_pyarrow_only_when_it_is_plain(tmp_path: Path, cell: str,
                                                        pyarrow: bool) -> None:
    """pyarrow reads large files of numbers only (never pulling in pandas); a file it would
    leave to numpy (here a NaN cell) is found out before pyarrow is imported."""
    from mocap_calib.io.formats.euroc import write_euroc_imu
    from mocap_calib.sim.flight import SimConfig, simulate_flight

    csv = write_euroc_imu(tmp_path / "imu.csv", simulate_flight(SimConfig(duration=5.0)).imu)
    with open(csv, "a") as f:
        f.write(f"99999999999999999,0.1,0.2,0.3,{cell},0.5,9.8\n")
    code = ("import sys\nfrom mocap_calib.io import tables\n"
            "from mocap_calib.io.formats.layout import read_table, sniff_layout\n"
            "tables.PYARROW_MIN_BYTES = 0\n"
            f"layout = sniff_layout({str(csv)!r})\n"
            "n = len(read_table(layout, range(7), 0).text[0])\n"
            "print(n, 'pyarrow' in sys.modules, 'pandas' in sys.modules)\n")
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                          timeout=120)
    assert proc.returncode == 0, proc.stderr
    n, loaded, pandas = proc.stdout.split()
    assert int(n) > 900 and loaded == str(pyarrow) and pandas == "False"


_ENDING = """
import atexit, sys
atexit.register(lambda: print("exit handler ran", file=sys.stderr))
sys.argv = ["mocap-calib", *sys.argv[1:]]
from mocap_calib.cli.main import main
main()
print("not reached")
"""


@pytest.mark.parametrize("args,code", [(["--help"], 0),
                                       (["calibrate", "--imu", "missing.csv", "--mocap",
                                         "missing.csv", "--out", "x.yaml"], 2)])
def test_the_process_ends_with_its_code_its_output_and_its_exit_handlers(
        args: list[str], code: int, tmp_path: Path) -> None:
    """The console entry ends the process without the interpreter's teardown: the exit code,
    everything printed (also into a pipe) and the exit handlers are kept."""
    proc = subprocess.run([sys.executable, "-c", _ENDING, *args], capture_output=True,
                          text=True, timeout=120, cwd=tmp_path)
    assert proc.returncode == code, proc.stderr
    assert "exit handler ran" in proc.stderr
    assert "not reached" not in proc.stdout
    if code == 0:
        assert "Usage:" in proc.stdout and "calibrate" in proc.stdout
    else:
        assert "error: " in proc.stderr and "missing.csv" in proc.stderr
