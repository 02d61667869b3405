"""Multi-view acquisition of the 24-view vase ring: photosurf vs pycolmap's sparse model.

One run, side by side, on ``fixtures/scenes/vase_ring.toml`` (1024x768; ``--quick``:
``vase_ring_small.toml``, 320x240):

* ``photosurf``        :func:`matching.multiview.reconstruct_multiview` with the known
  cameras: points, RMS distance to the truth mesh, seconds per view pair and in total;
* ``photosurf-sfm``    the same with pycolmap's cameras aligned to the truth by a
  similarity (Umeyama on the camera centres, :func:`matching.sfm.align_to_reference`);
  ``RMS icp``: after refining that similarity on the points (Umeyama to the closest
  truth points, 5 rounds, as the Tanks and Temples evaluation does);
* ``pycolmap-sparse``  pycolmap's own reconstruction of the same images (SIFT, exhaustive
  matching, incremental mapping, triangulated sparse points), aligned the same way;
* ``surface``          the photosurf cloud -> ``surface.reconstruct.surface_from_points`` ->
  Loop's sextic patches (``surface.bezier``) tessellated at level 2: Chamfer distance to
  the truth (``surface.metrics.compare_meshes``) and the time of the whole folder ->
  surface (acquisition + surface).

Goals: photosurf >= 20x the sparse points with <= 0.5x its RMS error; the folder
-> smooth surface in <= 60 s on this 2-core machine; surface Chamfer <= 0.1 % of the
object's height.

    .venv/bin/python benchmarks/multiview.py [--quick] [--json PATH] [--scene DIR]

``--temple DIR`` instead times ``photosurf acquire``'s work on the real temple ring with
its cameras (``templeSR_par.txt``), counts the LSM kernel's windows and iterations, and
runs OpenCV's SGBM on the same rectified pairs in the same process (goals: acquire
<= 10 s, <= 2x SGBM's time); ``--reference`` compares the cloud with an earlier one.

``--acquire-only`` times only the acquisition of the ring (``--scene`` or the recipe's
rendering) with its cameras: CPU and wall seconds, peak memory, how many of the 2 cores
the work kept busy (each thread's CPU sampled), the LSM work and the distances to the
true mesh (goals: acquire <= 25 s, >= 15 000 points/s); ``--temple`` reports the cores too.

``--kernel DIR`` (the temple folder) measures the LSM kernel alone on real windows: the
kernel calls of two of the ring's view pairs (``--kernel-pairs``) are recorded, then
replayed (``--repeats`` times, the fastest kept): windows per CPU-second, iterations,
and where the iterations end (the kernel's own status, before ``lsm_match``'s σ0,
correlation and step tests).
"""

from __future__ import annotations

import argparse
import itertools
import os
import sys
import tempfile
import threading
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from _common import print_goals, uptime, write_result  # noqa: E402

from matching.cameras import read_cameras  # noqa: E402
from matching.image_file import imread  # noqa: E402
from matching.multiview import reconstruct_multiview  # noqa: E402
from matching.sfm import align_to_reference, run_sfm  # noqa: E402
from pipeline.mesh_io import read_mesh  # noqa: E402
from surface import metrics  # noqa: E402

SAMPLES = 100_000
SEED = 0
LEVEL = 2


def _images(folder: Path, cameras) -> list:
    import cv2

    return [imread(str(folder / "images" / c.name), cv2.IMREAD_UNCHANGED) for c in cameras]


def _rms(points: np.ndarray, truth) -> float:
    if len(points) == 0:
        return float("nan")
    d = metrics.point_mesh_distance(points, *truth)
    return float(np.sqrt(np.mean(d**2)))


def _median(points: np.ndarray, truth) -> float:
    if len(points) == 0:
        return float("nan")
    return float(np.median(metrics.point_mesh_distance(points, *truth)))


def _rms_icp(points: np.ndarray, truth, iterations: int = 5) -> float:
    """RMS after refining the similarity on the points themselves (Umeyama to the closest
    truth points, repeated: the Tanks and Temples evaluation's ICP step)."""
    import open3d as o3d

    from matching.sfm import umeyama

    if len(points) < 3:
        return float("nan")
    scene = o3d.t.geometry.RaycastingScene()
    scene.add_triangles(o3d.core.Tensor(truth[0].astype(np.float32)),
                        o3d.core.Tensor(np.asarray(truth[1]).astype(np.uint32)))
    current = points
    for _ in range(iterations):
        closest = scene.compute_closest_points(o3d.core.Tensor(current.astype(np.float32)))
        s, R, t = umeyama(points, closest["points"].numpy().astype(np.float64))
        current = s * points @ R.T + t
    return _rms(current, truth)


def run_photosurf(name: str, images, cameras, truth, spacing: int) -> tuple[dict, object]:
    """``images`` a folder: ``photosurf acquire``'s path (images read from disk lazily)."""
    load_before, cpu0 = uptime(), time.process_time()
    start = time.perf_counter()
    if isinstance(images, Path):
        from pipeline.acquisition import acquire_folder

        cloud = acquire_folder(images, spacing=spacing)
    else:
        cloud = reconstruct_multiview(images, cameras, spacing=spacing)
    seconds = time.perf_counter() - start
    st = cloud.stats
    row = {"method": name, "points": len(cloud), "rms": _rms(cloud.points, truth),
           "median": _median(cloud.points, truth),
           "seconds": seconds, "cpu_seconds": time.process_time() - cpu0,
           "load_before": load_before, "load_after": uptime(), "workers": st.get("workers"),
           "seconds_per_pair": seconds / st["pairs"], "pairs": st["pairs"],
           "median_sigma": float(np.median(cloud.sigma)),
           "median_sigma_pair": st["median_sigma_pair"],
           "median_sigma_multiview": st["median_sigma_multiview"],
           "pair_seconds": st["pair_seconds"], "consistency_seconds": st["consistency_seconds"],
           "merge_seconds": st["merge_seconds"], "fused": st["fused"],
           "densify": st.get("densify"),
           "reasons": cloud.reason_counts}
    return row, cloud


def run_sparse(folder: Path, cameras, truth, work: Path):
    start = time.perf_counter()
    # the rendered cameras have no distortion; SIMPLE_RADIAL's k1 trades against the focal
    # length on a narrow field (tests/matching/test_multiview.py), so a pinhole model
    sfm = run_sfm(folder / "images", work_dir=work, camera_model="SIMPLE_PINHOLE")
    seconds = time.perf_counter() - start
    aligned, centre_rms = align_to_reference(sfm, cameras)
    row = {"method": "pycolmap-sparse", "points": int(len(aligned.points)),
           "rms": _rms(aligned.points, truth), "rms_icp": _rms_icp(aligned.points, truth),
           "median": _median(aligned.points, truth),
           "seconds": seconds,
           "registered": len(sfm.registered), "unregistered": list(sfm.unregistered),
           "camera_centre_rms": centre_rms,
           "mean_reprojection_error_px": sfm.mean_reprojection_error_px}
    return row, aligned


def run_surface(points: np.ndarray, truth, height: float) -> dict:
    """Sections -> curves -> stitch -> smooth (Loop's patches, tessellated): the stages of
    ``photosurf run`` after acquisition, through the same public steps."""
    from surface import bezier
    from surface.reconstruct import surface_from_points

    load_before, cpu0 = uptime(), time.process_time()
    start = time.perf_counter()
    note = ""
    try:
        stitched = surface_from_points(points, axis="z")
    except ValueError as exc:
        # surface_from_points' default section count can meet a loop it cannot fit
        # ("points all coincide") on the 1024x768 cloud; retry with a section every 0.05
        # (61 over the height, the recipe's profile sampling) and say so
        note = f"default sections failed ({exc}); 61 sections"
        try:
            stitched = surface_from_points(points, axis="z", sections=61)
        except ValueError as exc2:
            return {"method": "surface", "seconds": time.perf_counter() - start,
                    "error": f"surface_from_points: {exc2}", "chamfer_rel_height": float("nan")}
    surf = bezier.control_net(stitched.vertices, stitched.triangles)
    vertices, triangles, _ = bezier.tessellate(surf, LEVEL)
    seconds = time.perf_counter() - start
    cpu = time.process_time() - cpu0
    scores = metrics.compare_meshes(vertices, triangles, *truth, tau=0.001 * height,
                                    count=SAMPLES, seed=SEED)
    return {"method": "surface", "seconds": seconds, "cpu_seconds": cpu,
            "load_before": load_before, "load_after": uptime(),
            "closed": bool(stitched.closed),
            **({"note": note} if note else {}),
            "control_triangles": int(len(stitched.triangles)),
            "chamfer": float(scores["chamfer"]), "accuracy": float(scores["accuracy"]),
            "completeness": float(scores["completeness"]),
            "chamfer_rel_height": float(scores["chamfer"]) / height}


class _KernelCount:
    """Windows and Gauss-Newton iterations the LSM kernel (``matching.lsm._lsm_batch``)
    solved while installed (a wrapper keeping the kernel's ``targetoptions``, so the
    scheduler still sees it release the GIL)."""

    def __init__(self):
        from matching import lsm

        self._lsm, self._kernel = lsm, lsm._lsm_batch
        self.windows = self.iterations = self.calls = 0
        self._lock = threading.Lock()

    def __enter__(self):
        kernel = self._kernel

        def counted(*args):
            kernel(*args)
            with self._lock:
                self.calls += 1
                self.windows += len(args[3])
                self.iterations += int(args[-2].sum())

        counted.targetoptions = kernel.targetoptions
        self._lsm._lsm_batch = counted
        return self

    def __exit__(self, *exc):
        self._lsm._lsm_batch = self._kernel


class _ThreadCpu:
    """Each thread's CPU time in this process, sampled every ``period`` s while installed
    (Linux ``/proc/self/task``): how many cores the work kept busy, and the wall time
    ``cores`` idle cores would need for it -- per interval the larger of its busiest
    thread's CPU and the process's CPU over ``cores``, summed (a thread waiting for the
    GIL or a lock uses none, so a step that runs on one thread counts in full).  On a
    shared machine the wall time says little; this says where a core idles."""

    def __init__(self, period: float = 0.2, cores: int = 2):
        self.period, self.cores, self.samples = period, cores, []
        self._stop = threading.Event()
        self._tick = 1.0 / os.sysconf("SC_CLK_TCK") if hasattr(os, "sysconf") else 0.01

    def _cpu(self) -> dict:
        out = {}
        for tid in os.listdir("/proc/self/task"):
            try:
                fields = Path(f"/proc/self/task/{tid}/stat").read_text().rsplit(")", 1)[1].split()
            except OSError:  # the thread ended
                continue
            out[tid] = (int(fields[11]) + int(fields[12])) * self._tick
        return out

    def _run(self) -> None:
        while not self._stop.wait(self.period):
            self.samples.append(self._cpu())

    def __enter__(self):
        if Path("/proc/self/task").is_dir():
            self.samples.append(self._cpu())
            self._thread = threading.Thread(target=self._run, daemon=True)
            self._thread.start()
        return self

    def __exit__(self, *exc):
        self._stop.set()
        if self.samples:
            self._thread.join()
            self.samples.append(self._cpu())

    def summary(self) -> dict:
        """``cpu_seconds`` (threads' sum), ``idle_wall_seconds`` (``cores`` idle cores),
        ``busy_cores`` (their ratio) and ``one_thread_seconds`` (the intervals where one
        thread did at least 80 % of the work)."""
        cpu = wall = one = 0.0
        for a, b in itertools.pairwise(self.samples):
            d = sorted((b[t] - a.get(t, 0.0) for t in b), reverse=True) or [0.0]
            total, wall_i = sum(d), max(d[0], sum(d) / self.cores)
            cpu, wall = cpu + total, wall + wall_i
            one += wall_i if total > 0 and d[0] >= 0.8 * total else 0.0
        return {"cpu_seconds": cpu, "idle_wall_seconds": wall, "cores": self.cores,
                "busy_cores": cpu / wall if wall else float("nan"),
                "one_thread_seconds": one, "period": self.period}


def _chamfer(a: np.ndarray, b: np.ndarray) -> dict:
    """Mean nearest-neighbour distance each way between two clouds and their mean."""
    from scipy.spatial import cKDTree

    ab = cKDTree(b).query(a, workers=-1)[0]
    ba = cKDTree(a).query(b, workers=-1)[0]
    return {"a_to_b_mean": float(ab.mean()), "b_to_a_mean": float(ba.mean()),
            "chamfer": float(0.5 * (ab.mean() + ba.mean())),
            "a_to_b_median": float(np.median(ab))}


def run_temple(folder: Path, reference: str | None, cloud_out: str | None) -> dict:
    """The real temple ring with its cameras: ``photosurf acquire``'s work, timed and its
    LSM windows counted, against OpenCV's SGBM on the same rectified pairs, triangulated
    and fused the same way (``benchmarks/real.py``'s ``run_sgbm``), in this process."""
    from real import run_sgbm

    from pipeline.acquisition import acquire_folder

    cameras_file = folder / "templeSR_par.txt"
    load_before, cpu0, start = uptime(), time.process_time(), time.perf_counter()
    with _KernelCount() as count, _ThreadCpu() as threads:
        cloud = acquire_folder(folder, str(cameras_file))
    seconds, cpu = time.perf_counter() - start, time.process_time() - cpu0
    st = cloud.stats
    row = {"method": "photosurf", "points": len(cloud), "seconds": seconds,
           "cpu_seconds": cpu, "load_before": load_before, "load_after": uptime(),
           "workers": st.get("workers"), "pairs": st["pairs"],
           "pair_seconds": st["pair_seconds"], "consistency_seconds": st["consistency_seconds"],
           "merge_seconds": st["merge_seconds"], "lsm_calls": count.calls,
           "lsm_windows": count.windows, "lsm_iterations": count.iterations,
           "points_per_s": len(cloud) / seconds, "points_per_cpu_s": len(cloud) / cpu,
           "median_sigma": float(np.median(cloud.sigma)), "threads": threads.summary()}
    if cloud_out:
        np.savez(cloud_out, points=cloud.points, sigma=cloud.sigma)
    if reference:
        with np.load(reference) as ref:
            row["against_reference"] = {"reference": str(reference),
                                        "reference_points": int(len(ref["points"])),
                                        **_chamfer(cloud.points, ref["points"])}
    cameras = read_cameras(cameras_file)
    images = [imread(str(folder / c.name)) for c in cameras]
    cpu0, load = time.process_time(), uptime()
    sgbm = run_sgbm(images, cameras, [None] * len(cameras), 3)
    sgbm.update(cpu_seconds=time.process_time() - cpu0, load_before=load, load_after=uptime())
    return {"photosurf": row, "sgbm": sgbm,
            "ratio_to_sgbm": seconds / sgbm["seconds"],
            "cpu_ratio_to_sgbm": cpu / sgbm["cpu_seconds"]}


def run_acquire(folder: Path, truth, spacing: int) -> dict:
    """``photosurf acquire``'s work on a rendered ring with its cameras (``make demo``'s
    acquisition): CPU and wall seconds, the process's peak memory, the cores kept busy
    (:class:`_ThreadCpu`), the LSM kernel's work and the distances to the true mesh."""
    import resource

    from pipeline.acquisition import acquire_folder

    load_before, cpu0, start = uptime(), time.process_time(), time.perf_counter()
    with _KernelCount() as count, _ThreadCpu() as threads:
        cloud = acquire_folder(folder, spacing=spacing)
    seconds, cpu = time.perf_counter() - start, time.process_time() - cpu0
    d = metrics.point_mesh_distance(cloud.points, *truth)
    return {"method": "photosurf", "points": len(cloud), "seconds": seconds,
            "cpu_seconds": cpu, "load_before": load_before, "load_after": uptime(),
            "peak_rss_mib": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024,
            "threads": threads.summary(), "workers": cloud.stats.get("workers"),
            "lsm_calls": count.calls, "lsm_windows": count.windows,
            "lsm_iterations": count.iterations, "rms": float(np.sqrt(np.mean(d**2))),
            "median": float(np.median(d)),
            "within_3_sigma": float(np.mean(d <= 3 * cloud.sigma)),
            "points_per_s": len(cloud) / seconds, "points_per_cpu_s": len(cloud) / cpu}


def acquire_main(args, folder: Path, recipe: Path) -> int:
    truth = read_mesh(folder / "truth" / "mesh.ply")[:2]
    row = run_acquire(folder, truth, args.spacing)
    th = row["threads"]
    print(f"acquire {row['points']} points: {row['seconds']:.1f} s wall, {row['cpu_seconds']:.1f}"
          f" CPU-s (load {row['load_before']} -> {row['load_after']}); on {th['cores']} idle"
          f" cores {th['idle_wall_seconds']:.1f} s ({th['busy_cores']:.2f} busy, one thread"
          f" {th['one_thread_seconds']:.1f} s); peak {row['peak_rss_mib']:.0f} MiB; LSM"
          f" {row['lsm_windows']} windows, {row['lsm_iterations']} iterations; RMS to the"
          f" truth {row['rms']:.4g}, median {row['median']:.4g},"
          f" {100 * row['within_3_sigma']:.2f} % within 3 sigma")
    goals = {"acquire_le_25s": row["seconds"] <= 25.0,
             "points_per_s_ge_15000": row["points_per_s"] >= 15000}
    print_goals(goals)
    write_result(args.json, {"benchmark": "multiview-acquire", "recipe": recipe.name,
                             "scene": str(args.scene) if args.scene else None,
                             "photosurf": row, "goals": goals})
    return 0


def temple_main(args) -> int:
    folder = Path(args.temple)
    result = run_temple(folder, args.reference, args.cloud_out)
    ps, sg = result["photosurf"], result["sgbm"]
    print(f"{'method':12s}{'points':>9s}{'seconds':>9s}{'CPU s':>8s}  load before -> after")
    for r in (ps, sg):
        print(f"{r['method']:12s}{r['points']:9d}{r['seconds']:9.1f}{r['cpu_seconds']:8.1f}"
              f"  {r['load_before']} -> {r['load_after']}")
    print(f"photosurf / SGBM: {result['ratio_to_sgbm']:.2f} (wall), "
          f"{result['cpu_ratio_to_sgbm']:.2f} (CPU); LSM {ps['lsm_windows']} windows, "
          f"{ps['lsm_iterations']} iterations in {ps['lsm_calls']} calls; "
          f"{ps['points_per_s']:.0f} points/s ({ps['points_per_cpu_s']:.0f} per CPU-s)")
    th = ps["threads"]
    print(f"on {th['cores']} idle cores: {th['idle_wall_seconds']:.1f} s ({th['busy_cores']:.2f}"
          f" cores busy; one thread alone {th['one_thread_seconds']:.1f} s)")
    if "against_reference" in ps:
        ref = ps["against_reference"]
        print(f"against {ref['reference']}: {ps['points']} vs {ref['reference_points']} "
              f"points, Chamfer {ref['chamfer']:.3g} (median {ref['a_to_b_median']:.3g})")
    goals = {"temple_acquire_le_10s": ps["seconds"] <= 10.0,
             "temple_ratio_to_sgbm_le_2": result["ratio_to_sgbm"] <= 2.0}
    print_goals(goals)
    write_result(args.json, {"benchmark": "multiview-temple", **result, "goals": goals})
    return 0


class _KernelRecorder:
    """Records every ``matching.lsm._lsm_batch`` call's inputs (and the caller) while
    installed, so that the calls can be replayed on the kernel alone."""

    def __init__(self):
        from matching import lsm

        self._lsm, self._kernel = lsm, lsm._lsm_batch
        self.calls: list[tuple[str, tuple]] = []

    def __enter__(self):
        import inspect

        kernel = self._kernel

        def recorded(*args):
            # the lsm_match caller: the first frame outside matching/lsm.py
            caller = next(f.function for f in inspect.stack()[1:]
                          if not f.filename.endswith("lsm.py"))
            self.calls.append((caller, tuple(a.copy() if isinstance(a, np.ndarray) else a
                                            for a in args[:24])))
            kernel(*args)

        recorded.targetoptions = kernel.targetoptions
        self._lsm._lsm_batch = recorded
        return self

    def __exit__(self, *exc):
        self._lsm._lsm_batch = self._kernel


def _replay(kernel, inputs: tuple) -> tuple[np.ndarray, np.ndarray]:
    """One recorded call on ``kernel``: (status, iterations) per window."""
    n = len(inputs[3])
    out = [np.full((n, 8), np.nan), np.full((n, 2, 2), np.nan), np.full((n, 2, 2), np.nan),
           np.full((n, 6, 6), np.nan), np.full(n, np.nan), np.full((n, 4), np.nan),
           np.zeros(n, np.uint8), np.zeros(n, np.int32), np.zeros(n, np.bool_)]
    kernel(*inputs, *out)
    return out[6], out[7]


def run_kernel(folder: Path, pairs: list[int], repeats: int) -> dict:
    """The LSM kernel's rate on the windows of ``pairs`` (indices into
    :func:`matching.view_pairs.select_pairs`) of the temple ring."""
    from matching import lsm
    from matching.multiview import _search_volume, reconstruct_view_pair
    from matching.view_pairs import select_pairs

    cameras = read_cameras(folder / "templeSR_par.txt")
    images = [imread(str(folder / c.name)) for c in cameras]
    chosen = select_pairs(cameras)
    volume = _search_volume(cameras, None, None)
    with _KernelRecorder() as rec:
        for p in pairs:
            a, b = chosen[p]
            reconstruct_view_pair(images[a], images[b], cameras[a], cameras[b], (a, b),
                                  volume=volume)
    windows = sum(len(inputs[3]) for _, inputs in rec.calls)
    best, load = float("inf"), uptime()
    for _ in range(repeats):
        cpu0 = time.process_time()
        results = [_replay(lsm._lsm_batch, inputs) for _, inputs in rec.calls]
        best = min(best, time.process_time() - cpu0)
    status = np.concatenate([r[0] for r in results])
    iters = np.concatenate([r[1] for r in results]).astype(np.int64)
    by_caller: dict = {}
    for (caller, inputs), (_, it) in zip(rec.calls, results, strict=True):
        row = by_caller.setdefault(caller, {"windows": 0, "iterations": 0})
        row["windows"] += len(inputs[3])
        row["iterations"] += int(it.sum())
    names = {int(s): s.name.lower() for s in lsm.Status}
    ends = {names.get(int(s), str(int(s))): {"windows": int(np.sum(status == s)),
                                             "iterations": int(iters[status == s].sum())}
            for s in np.unique(status)}
    return {"pairs": [list(chosen[p]) for p in pairs], "calls": len(rec.calls),
            "windows": windows, "iterations": int(iters.sum()), "cpu_seconds": best,
            "repeats": repeats, "windows_per_cpu_s": windows / best,
            "iterations_per_cpu_s": float(iters.sum()) / best, "load_before": load,
            "load_after": uptime(), "by_caller": by_caller, "ends": ends}


def kernel_main(args) -> int:
    pairs = [int(v) for v in args.kernel_pairs.split(",")]
    row = run_kernel(Path(args.kernel), pairs, args.repeats)
    print(f"LSM kernel on {row['windows']} temple windows (pairs {row['pairs']}, "
          f"{row['calls']} calls): {row['cpu_seconds']:.2f} CPU-s, "
          f"{row['windows_per_cpu_s']:.0f} windows/CPU-s, {row['iterations']} iterations; "
          f"load {row['load_before']} -> {row['load_after']}")
    print(f"{'ends as':20s}{'windows':>9s}{'iterations':>12s}{'share':>7s}")
    for name, r in row["ends"].items():
        print(f"{name:20s}{r['windows']:9d}{r['iterations']:12d}"
              f"{r['iterations'] / max(row['iterations'], 1):7.1%}")
    goals = {"kernel_windows_per_s_2_cores_ge_150000": 2 * row["windows_per_cpu_s"] >= 150_000}
    print_goals(goals)
    write_result(args.json, {"benchmark": "lsm-kernel-temple", **row, "goals": goals})
    return 0


def print_table(rows: list[dict]) -> None:
    print(f"{'method':18s}{'points':>9s}{'RMS':>11s}{'RMS icp':>11s}{'median':>11s}"
          f"{'seconds':>9s}{'CPU s':>8s}"
          f"{'s/pair':>8s}{'Chamfer':>11s}  load (1/5/15 min) before -> after")
    for r in rows:
        cells = [_cell(r, "points", 9, "d"), _cell(r, "rms", 11, ".6f"),
                 _cell(r, "rms_icp", 11, ".6f"), _cell(r, "median", 11, ".6f"),
                 _cell(r, "seconds", 9, ".1f"), _cell(r, "cpu_seconds", 8, ".1f"),
                 _cell(r, "seconds_per_pair", 8, ".2f"),
                 _cell(r, "chamfer", 11, ".6f")]
        load = f"  {r['load_before']} -> {r['load_after']}" if "load_before" in r else ""
        print(f"{r['method']:18s}" + "".join(cells) + load)


def _cell(row: dict, key: str, width: int, fmt: str) -> str:
    value = row.get(key)
    return f"{value:>{width}{fmt}}" if isinstance(value, int | float) else " " * width


def _parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="the 320x240 ring")
    parser.add_argument("--json", default=None,
                        help="result file (default benchmarks/results/multiview.json; with "
                             "--temple multiview_temple.json, with --kernel lsm_kernel.json, "
                             "with --acquire-only multiview_demo.json)")
    parser.add_argument("--scene", default=None,
                        help="an already rendered scene folder (photosurf synth) to reuse")
    parser.add_argument("--spacing", type=int, default=3,
                        help="candidate spacing, px (default 3, photosurf's default)")
    parser.add_argument("--cloud-out", default=None,
                        help="also save photosurf's cloud (known cameras) to this .npz")
    parser.add_argument("--temple", default=None, metavar="DIR",
                        help="instead: the real temple ring with its cameras (e.g. "
                             "../shared/data/real/temple_sparse_ring) against SGBM")
    parser.add_argument("--reference", default=None, metavar="CLOUD.npz",
                        help="with --temple: a previous cloud (--cloud-out) to compare with")
    parser.add_argument("--acquire-only", action="store_true",
                        help="only photosurf's acquisition of the ring with its cameras: CPU, "
                             "wall, peak memory, cores kept busy, truth distances")
    parser.add_argument("--kernel", default=None, metavar="DIR",
                        help="instead: the LSM kernel alone on the temple ring's windows")
    parser.add_argument("--kernel-pairs", default="0,5",
                        help="with --kernel: indices of the ring's view pairs (default 0,5)")
    parser.add_argument("--repeats", type=int, default=3,
                        help="with --kernel: replays, the fastest kept (default 3)")
    return parser


def main(argv: list[str] | None = None) -> int:
    args = _parser().parse_args(argv)
    if args.json is None:
        name = ("lsm_kernel" if args.kernel else "multiview_temple" if args.temple
                else "multiview_demo" if args.acquire_only else "multiview")
        name += "_quick" if args.quick and args.acquire_only else ""
        args.json = str(ROOT / "benchmarks" / "results" / f"{name}.json")
    if args.kernel:
        return kernel_main(args)
    if args.temple:
        return temple_main(args)

    import open3d as o3d

    from pipeline.scenes import render_scene

    o3d.utility.set_verbosity_level(o3d.utility.VerbosityLevel.Error)
    recipe = ROOT / "fixtures" / "scenes" / ("vase_ring_small.toml" if args.quick
                                             else "vase_ring.toml")
    with tempfile.TemporaryDirectory(prefix="photosurf-mv-") as tmp:
        tmp = Path(tmp)
        folder = Path(args.scene) if args.scene else tmp / "scene"
        if not args.scene:
            start = time.perf_counter()
            render_scene(recipe, folder, progress=False)
            print(f"rendered {recipe.name} in {time.perf_counter() - start:.0f} s", flush=True)
        if args.acquire_only:
            return acquire_main(args, folder, recipe)
        cameras = read_cameras(folder / "cameras.yml")
        images = _images(folder, cameras)
        truth = read_mesh(folder / "truth" / "mesh.ply")[:2]
        height = float(np.ptp(truth[0][:, 2]))
        w, h = cameras[0].size
        print(f"{len(cameras)} views {w}x{h}; object height {height:g}", flush=True)

        # photosurf acquire's own path: the folder, images read as tasks need them
        known, cloud = run_photosurf("photosurf", folder, cameras, truth, args.spacing)
        print(f"  photosurf: {known['seconds']:.1f} s", flush=True)
        if args.cloud_out:
            np.savez(args.cloud_out, points=cloud.points, sigma=cloud.sigma, views=cloud.views,
                     colours=cloud.colours)
        surface = run_surface(cloud.points, truth, height)
        surface["folder_to_surface_seconds"] = known["seconds"] + surface["seconds"]
        print(f"  surface: {surface['seconds']:.1f} s {surface.get('error', '')}"
              f"{surface.get('note', '')}", flush=True)
        sparse, aligned = run_sparse(folder, cameras, truth, tmp / "sfm")
        print(f"  pycolmap: {sparse['seconds']:.1f} s", flush=True)
        by_name = {c.name: c for c in aligned.cameras}
        rows = [known, sparse, surface]
        if all(c.name in by_name for c in cameras):
            with_sfm, sfm_cloud = run_photosurf("photosurf-sfm", images,
                                        [by_name[c.name] for c in cameras], truth,
                                        args.spacing)
            with_sfm["rms_icp"] = _rms_icp(sfm_cloud.points, truth)
            rows.insert(1, with_sfm)
        else:
            print(f"  photosurf-sfm skipped: SfM left out {', '.join(sparse['unregistered'])}")
    print()
    print_table(rows)
    sfm_row = next((r for r in rows if r["method"] == "photosurf-sfm"), None)
    # folder -> smooth surface: acquisition (images read from the folder, cameras given)
    # + sections, curves, stitching and Loop's patches; not the scene rendering (the
    # folder is the input), the pycolmap peer, the export or the report
    goals = {
        "points_ge_20x_sparse": known["points"] >= 20 * sparse["points"],
        "rms_le_half_sparse": known["rms"] <= 0.5 * sparse["rms"],
        "folder_to_surface_le_60s": surface["folder_to_surface_seconds"] <= 60.0,
        "chamfer_le_0.1pct_height": surface["chamfer_rel_height"] <= 0.001,
        "sfm_poses_rms_le_2x_known": (sfm_row is not None
                                      and sfm_row["rms_icp"] <= 2 * known["rms"]),
    }
    print(f"\npoints ratio {known['points'] / max(sparse['points'], 1):.1f}x, RMS ratio "
          f"{known['rms'] / sparse['rms']:.3f}, folder -> smooth surface "
          f"{surface['folder_to_surface_seconds']:.1f} s (acquire {known['seconds']:.1f} s + "
          f"sections..smooth {surface['seconds']:.1f} s; CPU "
          f"{known['cpu_seconds'] + surface['cpu_seconds']:.1f} s on {known['workers']} "
          f"threads; load {known['load_before']} -> {surface['load_after']}), Chamfer "
          f"{100 * surface['chamfer_rel_height']:.3f} % of the height")
    print_goals(goals)
    result = {"benchmark": "multiview", "recipe": recipe.name, "views": len(cameras),
              "image_size": [w, h], "spacing": args.spacing, "quick": bool(args.quick),
              "rows": rows, "goals": goals, "samples": SAMPLES, "level": LEVEL}
    write_result(args.json, result)
    return 0


if __name__ == "__main__":
    sys.exit(main())
