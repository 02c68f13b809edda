"""Calibrate EuRoC V2_03_difficult and compare with the dataset's own reference values.

Three columns per parameter:
- ours: `mocap-calib calibrate` on imu0 + vicon0 (default model base+time_offset);
- published: vicon0/sensor.yaml's T_BS (= T_IM, so T_MI = T_BS^-1); it gives no clock offset;
- ground truth: what state_groundtruth_estimate0 implies. Its poses are the IMU (body) frame on
  the IMU clock, so T_MI(t) = T_WM(t + t_d)^-1 T_WB(t); t_d is found by minimising the scatter
  of T_MI(t) over the session, and T_MI is the mean at that t_d. Its biases are the mean of
  the file's bias columns.

Prints the comparison, then the table of docs/validation.md (``--write-doc`` rewrites its
section there).

Usage: python scripts/euroc_reference.py [path/to/mav0] [--write-doc] [--doc PATH]
       (default mav0: ../shared/data/euroc_V2_03_difficult/mav0)
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
from _doc_section import add_doc_options, check, provenance, table, write
from _shared_data import DATA
from scipy.optimize import minimize_scalar

from mocap_calib.core.model import so3
from mocap_calib.core.options import CalibrationOptions
from mocap_calib.io.formats.euroc import read_euroc_poses, read_t_bs
from mocap_calib.workflows.calibrate import CalibrateRequest, InputSpec, run_calibration

SECTIONS = ("euroc_reference",)

DEFAULT = DATA / "euroc_V2_03_difficult" / "mav0"


def _interp_poses(t_q, t, R, p):
    """Poses at times t_q (slerp via rotation vectors of consecutive pairs, linear position)."""
    i = np.clip(np.searchsorted(t, t_q) - 1, 0, len(t) - 2)
    a = ((t_q - t[i]) / (t[i + 1] - t[i]))[:, None]
    dR = so3.log(np.einsum("nji,njk->nik", R[i], R[i + 1]))
    return R[i] @ so3.exp(a * dR), p[i] + a * (p[i + 1] - p[i])


def gt_implied(root: Path) -> dict[str, object]:
    vic = read_euroc_poses(root / "vicon0" / "data.csv")
    gt_path = root / "state_groundtruth_estimate0" / "data.csv"
    gt = read_euroc_poses(gt_path)
    cols = np.loadtxt(gt_path, delimiter=",", skiprows=1, usecols=range(11, 17))
    tv = vic.t + (vic.time_origin_ns - gt.time_origin_ns) * 1e-9  # on the GT (IMU) origin
    tg = gt.t
    Rv, pv = vic.rotation, vic.position
    Rg, pg = gt.rotation, gt.position
    dt_v = np.diff(tv)
    gap_ok = np.concatenate([[True], dt_v < 0.03])

    def T_MI_series(t_d: float):
        tq = tg + t_d
        ok = (tq > tv[1]) & (tq < tv[-2])
        i = np.clip(np.searchsorted(tv, tq[ok]), 1, len(tv) - 1)
        ok_idx = np.flatnonzero(ok)[gap_ok[i]]
        R_WM, p_WM = _interp_poses(tg[ok_idx] + t_d, tv, Rv, pv)
        R_MI = np.einsum("nji,njk->nik", R_WM, Rg[ok_idx])
        p_MI = np.einsum("nji,nj->ni", R_WM, pg[ok_idx] - p_WM)
        return R_MI, p_MI

    def scatter(t_d: float) -> float:
        # Attitude only: the ground truth's positions are smoothed by its own estimator, and
        # a lever-arm error would trade with the time offset.
        R_MI, _ = T_MI_series(t_d)
        R_mean = _mean_rotation(R_MI)
        rot = so3.log(np.einsum("ji,njk->nik", R_mean, R_MI))
        return float(np.mean(np.sum(rot**2, axis=1)))

    # Coarse grid, then a bounded scalar search around the best.
    grid = np.arange(-0.4, 0.4, 0.002)
    best = grid[int(np.argmin([scatter(t) for t in grid]))]
    t_d = float(minimize_scalar(scatter, bounds=(best - 0.004, best + 0.004), method="bounded",
                                options={"xatol": 1e-6}).x)
    R_MI, p_MI = T_MI_series(t_d)
    R_mean = _mean_rotation(R_MI)
    rot_sc = np.degrees(np.sqrt(np.mean(so3.log(np.einsum("ji,njk->nik", R_mean, R_MI)) ** 2, 0)))
    return {"R_MI": R_mean, "p_MI": p_MI.mean(axis=0), "p_scatter_mm": 1e3 * p_MI.std(axis=0),
            "rot_scatter_deg": rot_sc, "time_offset": t_d,  # both clocks on the GT origin
            "gyro_bias": cols[:, 0:3].mean(axis=0), "accel_bias": cols[:, 3:6].mean(axis=0),
            "gyro_bias_range": np.ptp(cols[:, 0:3], axis=0),
            "accel_bias_range": np.ptp(cols[:, 3:6], axis=0)}


def _mean_rotation(R: np.ndarray) -> np.ndarray:
    U, _, Vt = np.linalg.svd(R.mean(axis=0))
    return U @ np.diag([1.0, 1.0, np.sign(np.linalg.det(U @ Vt))]) @ Vt


def _vec(x, fmt: str, scale: float = 1.0) -> str:
    return "[" + ", ".join(format(a * scale, fmt) for a in np.asarray(x, float)) + "]"


def _ang(Ra: np.ndarray, Rb: np.ndarray) -> float:
    return float(np.degrees(np.linalg.norm(so3.log(Ra.T @ Rb))))


def markdown(res, T_MI_pub: np.ndarray, gt: dict) -> str:
    """The section of docs/validation.md: ours, the published T_BS and the ground truth's."""
    R_ours = so3.quat_to_rotmat(res.rotation_wxyz)
    s_rot = np.degrees(res.sigma_rotation)
    p_pub, p_gt = T_MI_pub[:3, 3], gt["p_MI"]
    tilt = np.degrees(np.arccos(-res.gravity_in_mocap[2]))
    rows = [
        ["`R_MI` (quaternion wxyz)", f"{_vec(res.rotation_wxyz, '.5f')}, sigma "
         f"{s_rot.min():.2f}-{s_rot.max():.2f} deg",
         f"{_ang(T_MI_pub[:3, :3], R_ours):.2f} deg away",
         f"{_ang(gt['R_MI'], R_ours):.2f} deg away"],
        ["`p_MI` (mm)", f"{_vec(res.translation, '.1f', 1e3)} +- "
         f"{_vec(res.sigma_translation, '.1f', 1e3)}",
         f"{_vec(p_pub, '.1f', 1e3)} ({1e3 * np.linalg.norm(p_pub - res.translation):.1f} mm away)",
         f"{_vec(p_gt, '.1f', 1e3)} ({1e3 * np.linalg.norm(p_gt - res.translation):.1f} mm away)"],
        ["`t_d` (ms)", f"{1e3 * res.time_offset:.2f} +- {1e3 * res.sigma_time_offset:.2f}",
         "not given", f"{1e3 * gt['time_offset']:.2f}"],
        ["gyro bias (1e-3 rad/s)", f"{_vec(res.gyro_bias, '.2f', 1e3)} +- "
         f"{_vec(res.sigma_gyro_bias, '.2f', 1e3)}", "-",
         f"{_vec(gt['gyro_bias'], '.2f', 1e3)} (mean of its bias columns)"],
        ["accel bias (m/s^2)", f"{_vec(res.accel_bias, '.3f')} +- "
         f"{_vec(res.sigma_accel_bias, '.3f')}", "-",
         f"{_vec(gt['accel_bias'], '.3f')} (mean; range over the file "
         f"{np.max(gt['accel_bias_range']):.3f})"],
        ["tilt of the Vicon z axis", f"{tilt:.2f} +- {np.degrees(res.sigma_gravity.max()):.2f} "
         "deg from vertical", "-", "-"],
    ]
    return (provenance("euroc_reference.py") + "\n"
            + table(["parameter", "mocap-calib", "published `vicon0/sensor.yaml`",
                     "implied by the ground truth"], rows) + "\n"
            f"The published `T_BS` and the ground truth's `T_MI` differ by "
            f"{_ang(T_MI_pub[:3, :3], gt['R_MI']):.2f} deg and "
            f"{1e3 * np.linalg.norm(p_pub - p_gt):.1f} mm. The ground truth's own `T_MI` "
            f"scatters over the session by {gt['rot_scatter_deg'].min():.2f}-"
            f"{gt['rot_scatter_deg'].max():.2f} deg and {gt['p_scatter_mm'].min():.1f}-"
            f"{gt['p_scatter_mm'].max():.1f} mm (RMS per axis).\n")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("mav0", nargs="?", type=Path, default=DEFAULT,
                        help=f"EuRoC mav0 folder (default {DEFAULT})")
    add_doc_options(parser)
    args = parser.parse_args()
    check(args, list(SECTIONS))
    root = args.mav0
    res, _ = run_calibration(CalibrateRequest(inputs=InputSpec(mav0=root),
                                              options=CalibrationOptions()))
    T_IM = read_t_bs(root / "vicon0" / "sensor.yaml")
    T_MI_pub = np.linalg.inv(T_IM)
    gt = gt_implied(root)
    R_ours = so3.quat_to_rotmat(res.rotation_wxyz)

    def ang(Ra, Rb):
        return float(np.degrees(np.linalg.norm(so3.log(Ra.T @ Rb))))

    def v(x, s=1.0):
        return "[" + ", ".join(f"{a * s:8.3f}" for a in np.asarray(x, float)) + "]"

    print(f"session: {root}")
    print(f"model {res.model}; chi2/dof {res.solver.position_chi2_per_dof}; notes: "
          + " | ".join(res.notes))
    print()
    def q(R):
        return "[" + ", ".join(f"{a:8.5f}" for a in so3.rotmat_to_quat(R)) + "]"

    print("R_MI (quaternion wxyz)")
    print(f"  ours        {q(R_ours)}  sigma {v(np.degrees(res.sigma_rotation))} deg")
    print(f"  published   {q(T_MI_pub[:3, :3])}  "
          f"(ours differs by {ang(T_MI_pub[:3, :3], R_ours):.3f} deg)")
    print(f"  groundtruth {q(gt['R_MI'])}  (ours differs by {ang(gt['R_MI'], R_ours):.3f} deg;"
          f" GT scatter {v(gt['rot_scatter_deg'])} deg)")
    print(f"  published vs groundtruth: {ang(T_MI_pub[:3, :3], gt['R_MI']):.3f} deg")
    print("p_MI (mm)")
    print(f"  ours        {v(res.translation, 1e3)}  +- {v(res.sigma_translation, 1e3)}")
    print(f"  published   {v(T_MI_pub[:3, 3], 1e3)}  (|diff| "
          f"{1e3 * np.linalg.norm(T_MI_pub[:3, 3] - res.translation):.2f} mm)")
    print(f"  groundtruth {v(gt['p_MI'], 1e3)}  (|diff| "
          f"{1e3 * np.linalg.norm(gt['p_MI'] - res.translation):.2f} mm; GT scatter "
          f"{v(gt['p_scatter_mm'])})")
    print(f"  published vs groundtruth: "
          f"{1e3 * np.linalg.norm(T_MI_pub[:3, 3] - gt['p_MI']):.2f} mm")
    print("time offset t_d (ms)")
    print(f"  ours        {res.time_offset * 1e3:9.3f} +- {res.sigma_time_offset * 1e3:.3f}")
    print(f"  groundtruth {gt['time_offset'] * 1e3:9.3f}   (published: none)")
    print("gyro bias (rad/s)")
    print(f"  ours        {v(res.gyro_bias, 1e3)} e-3  +- {v(res.sigma_gyro_bias, 1e3)} e-3")
    print(f"  groundtruth {v(gt['gyro_bias'], 1e3)} e-3  (mean; range over the file "
          f"{v(gt['gyro_bias_range'], 1e3)} e-3)")
    print("accel bias (m/s^2)")
    print(f"  ours        {v(res.accel_bias)}  +- {v(res.sigma_accel_bias)}")
    print(f"  groundtruth {v(gt['accel_bias'])}  (mean; range {v(gt['accel_bias_range'])})")
    tilt = np.degrees(np.arccos(-res.gravity_in_mocap[2]))
    print(f"gravity: tilt of the Vicon z axis from vertical {tilt:.3f} deg "
          f"+- {np.degrees(res.sigma_gravity.max()):.3f}; direction {v(res.gravity_in_mocap)}")
    print()
    text = markdown(res, T_MI_pub, gt)
    print(text)
    write(args, {"euroc_reference": text})


if __name__ == "__main__":
    main()
