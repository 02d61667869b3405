"""End-to-end figures of ``photosurf run`` and of the Dask executor.

1. Time per stage of the default demo (the 24-view ring ``vase_ring.toml``, as
   ``make demo`` runs it, view pairs on the in-process executor) and of the
   stereo pair (``vase.toml``: one side of the vase, so the run stops after the
   curves), read from the workspace manifests, and the
   peak resident memory of the process so far (``resource.getrusage``:
   ``ru_maxrss``).  The first acquisition of a process includes numba's
   compilation of the LSM kernels.
2. Dask ``LocalCluster`` (2 worker processes) against the in-process default
   on 12 view pairs of the rendered ring (``matching.multiview`` with the
   executor's ``map``), and on a batch of independent objects (noisy vase
   clouds, cloud → stitched and smoothed surface): wall time of the tasks
   alone (cluster already up) and the cluster's start-up, CPU seconds (this
   process, and the workers'), and whether the results are identical.  The
   in-process default already runs the view pairs on one thread per core.
3. The demo's back end ("smooth + export + report <= 15 s"): the smooth,
   export and report stages of the demo run above, and the same three stages run again
   on its workspace (``--from smooth --to report --force``, in this process: numba's
   kernels loaded, imports done), with the patches and triangles they handled.
4. Peak memory of ``photosurf acquire`` on a 24- and a 72-view ring
   (1024×768), each in a fresh process (``ru_maxrss``), against the same
   process after its imports only and the bytes of the final cloud: memory is
   bounded when peak − imports − cloud does not grow with the views.

Every timing is printed with the CPU seconds and the load averages before and
after (the machine is shared).

Usage::

    .venv/bin/python benchmarks/pipeline.py [--quick] [--back-end] [--json PATH]

``--quick`` renders the scenes at 256×192 and uses 4 smaller objects; ``--back-end``
runs only items 1 (the ring) and 3.
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import shutil
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from _common import uptime  # noqa: E402

from pipeline import config as config_mod  # noqa: E402
from pipeline import progress  # noqa: E402
from pipeline.batch import run_object  # noqa: E402
from pipeline.engine import run_pipeline  # noqa: E402
from pipeline.executor import DaskExecutor, LocalExecutor  # noqa: E402
from pipeline.plan import STAGE_ORDER  # noqa: E402


def children_cpu() -> float:
    """CPU seconds of the finished child processes (Dask workers once closed)."""
    ru = resource.getrusage(resource.RUSAGE_CHILDREN)
    return ru.ru_utime + ru.ru_stime


def peak_rss_mib() -> float:
    """Peak resident set size of this process so far, MiB (Linux reports KiB)."""
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


def demo(workdir: Path, recipe: str, quick: bool, label: str) -> dict:
    """Run a scene recipe end to end in this process; per-stage seconds and status.

    ``quick`` renders at a quarter of the recipe's 1024x768 (focal length scaled alike).
    """
    assignments = ["scene.overrides.cameras.width=256", "scene.overrides.cameras.height=192",
                   "scene.overrides.cameras.focal_px=332.8",
                   "scene.overrides.shape.triangles=20000"] if quick else []
    config = config_mod.resolve(None, assignments)
    load_before, cpu0 = uptime(), time.process_time()
    t0 = time.perf_counter()
    error = None
    try:
        run_pipeline([ROOT / recipe], workdir / label, config)
    except ValueError as exc:  # a stage failed: report it with the timings we have
        error = str(exc)
    total = time.perf_counter() - t0
    manifest = json.loads((workdir / label / "manifest.json").read_text())
    recorded = manifest["stages"]
    stages = {name: {"status": recorded[name].get("status"),
                     "seconds": recorded[name].get("seconds"),
                     "peak_rss_mib": recorded[name].get("peak_rss_mib"),
                     **({"reason": recorded[name]["reason"]}
                        if recorded[name].get("reason") else {}),
                     **({"info": recorded[name]["info"]} if recorded[name].get("info") else {})}
              for name in STAGE_ORDER if name in recorded}
    return {"recipe": recipe, "quick": quick, "assignments": assignments,
            "total_seconds": total, "stages": stages,
            "cpu_seconds": time.process_time() - cpu0, "load_before": load_before,
            "load_after": uptime(), "error": error, "peak_rss_mib": peak_rss_mib()}


def scene_cached(workdir: Path, demo_figures: dict, recipe: str, label: str) -> dict:
    """The demo's scene stage again in a new workspace: the rendered views copied from the
    scene cache (``pipeline.scene_cache``) that the demo run filled, not rendered."""
    config = config_mod.resolve(None, demo_figures.get("assignments", []))
    t0, cpu0 = time.perf_counter(), time.process_time()
    run_pipeline([ROOT / recipe], workdir / label, config, stop="scene")
    manifest = json.loads((workdir / label / "manifest.json").read_text())
    rendered = demo_figures["stages"].get("scene", {}).get("seconds")
    return {"seconds": time.perf_counter() - t0, "cpu_seconds": time.process_time() - cpu0,
            "stage_seconds": manifest["stages"]["scene"].get("seconds"),
            "rendered_seconds": rendered, "load_after": uptime()}


#: The demo's back end and its goal, seconds.
BACK_END = ("smooth", "export", "report")
BACK_END_GOAL_SECONDS = 15.0


def back_end(workdir: Path, demo_figures: dict, recipe: str, label: str) -> dict:
    """Seconds of the back-end stages in the demo run and when run again on its workspace."""
    config = config_mod.resolve(None, demo_figures.get("assignments", []))
    load_before, cpu0 = uptime(), time.process_time()
    run_pipeline([ROOT / recipe], workdir / label, config, start=BACK_END[0],
                 stop=BACK_END[-1], force=True)
    manifest = json.loads((workdir / label / "manifest.json").read_text())
    again = {name: manifest["stages"][name].get("seconds") for name in BACK_END}
    first = {name: demo_figures["stages"].get(name, {}).get("seconds") for name in BACK_END}
    smooth = manifest["stages"]["smooth"].get("info", {})
    report = manifest["stages"]["report"].get("info", {})
    return {"first_run": first, "rerun": again,
            "first_total": sum(v for v in first.values() if v is not None),
            "rerun_total": sum(v for v in again.values() if v is not None),
            "patches": smooth.get("patches"), "triangles": smooth.get("triangles"),
            "smooth_chamfer": report.get("metrics", {}).get("smooth surface", {}).get(
                "chamfer"),
            "cpu_seconds": time.process_time() - cpu0, "load_before": load_before,
            "load_after": uptime()}


def _cloud(path: Path, seed: int, n: int) -> None:
    rng = np.random.default_rng(seed)
    z = rng.uniform(0, 3, n)
    theta = rng.uniform(0, 2 * np.pi, n)
    r = 1 + 0.3 * np.sin(2 * z)
    points = np.column_stack([r * np.cos(theta), r * np.sin(theta), z])
    np.savetxt(path, points + rng.normal(0, 0.002, (n, 3)))


def _tasks(workdir: Path, label: str, count: int, n_points: int) -> list[dict]:
    tasks = []
    for k in range(count):
        cloud = workdir / f"object_{k}.xyz"
        if not cloud.exists():
            _cloud(cloud, k, n_points)
        tasks.append({"name": f"object_{k}", "inputs": [str(cloud)], "kind": "cloud",
                      "rig": None, "outdir": str(workdir / label / f"object_{k}"),
                      "config_files": [], "assignments": ["report.samples=5000"],
                      "overrides": {}, "stop": "export"})
    return tasks


def _warm_up() -> None:
    """Import what a task needs, once per worker process."""
    import open3d  # noqa: F401

    import pipeline.engine  # noqa: F401
    import surface.bezier  # noqa: F401
    import surface.catmull_rom  # noqa: F401
    import surface.stitch  # noqa: F401
    import surface.topology  # noqa: F401


def _outputs(outdir: str) -> dict:
    manifest = json.loads((Path(outdir) / "manifest.json").read_text())
    return {rel: digest for name, rec in manifest["stages"].items()
            if name in ("acquire", "sections", "curves", "stitch", "smooth")
            for rel, digest in rec.get("outputs", {}).items()}


def dask_speedup(workdir: Path, quick: bool) -> dict:
    """In-process vs LocalCluster(2) on a batch of independent objects."""
    count, n_points = (4, 3000) if quick else (8, 8000)
    local_tasks = _tasks(workdir, "local", count, n_points)
    t0 = time.perf_counter()
    local = LocalExecutor().map(run_object, local_tasks)
    t_local = time.perf_counter() - t0

    dask_tasks = _tasks(workdir, "dask", count, n_points)
    t0 = time.perf_counter()
    with DaskExecutor(None, n_workers=2) as ex:
        ex.client.run(_warm_up)  # imports (open3d, numba kernels) belong to the start-up
        t_up = time.perf_counter() - t0
        t1 = time.perf_counter()
        remote = ex.map(run_object, dask_tasks)
        t_tasks = time.perf_counter() - t1
    t_total = time.perf_counter() - t0
    identical = all(_outputs(a["outdir"]) == _outputs(b["outdir"])
                    for a, b in zip(local, remote, strict=True))
    return {"objects": count, "points_per_object": n_points, "cpu_count": os.cpu_count(),
            "in_process_seconds": t_local, "dask_tasks_seconds": t_tasks,
            "dask_startup_seconds": t_up, "dask_total_seconds": t_total,
            "speedup_tasks": t_local / t_tasks, "speedup_with_startup": t_local / t_total,
            "identical_outputs": identical,
            "failed": [r["name"] for r in local + remote if r["status"] != "done"]}


def _images_and_cameras(scene: Path):
    """The folder as ``photosurf run`` loads it: images read lazily, cameras by name."""
    from pipeline.inputs import load_folder

    loaded = load_folder(scene)
    return loaded["images"], loaded["cameras"]


def pair_speedup(workdir: Path, n_pairs: int = 12) -> dict:
    """12 view pairs of the rendered ring: in-process vs LocalCluster(2), same cloud?"""
    from matching.multiview import reconstruct_multiview, select_pairs

    images, cameras = _images_and_cameras(workdir / "ring" / "scene")
    pairs = select_pairs(cameras)[:n_pairs]
    load_before, cpu0 = uptime(), time.process_time()
    t0 = time.perf_counter()
    # the in-process default: the executor's plain loop is not used for view pairs,
    # reconstruct_multiview runs them on one thread per core
    local = reconstruct_multiview(images, cameras, pairs=pairs)
    t_local = time.perf_counter() - t0
    cpu_local = time.process_time() - cpu0
    load_mid = uptime()
    t0 = time.perf_counter()
    children0 = children_cpu()
    with DaskExecutor(None, n_workers=2) as ex:
        ex.client.run(_warm_up)
        ex.map(_square, [1, 2])  # the workers have served a task
        t_up = time.perf_counter() - t0
        t1 = time.perf_counter()
        cpu1 = time.process_time()
        remote = reconstruct_multiview(images, cameras, pairs=pairs, map_func=ex.map)
        t_tasks = time.perf_counter() - t1
        cpu_client = time.process_time() - cpu1
    same = {name: bool(np.array_equal(getattr(local, name), getattr(remote, name)))
            for name in ("points", "sigma", "views", "colours")}
    return {"pairs": len(pairs), "views": len(cameras), "image_size": list(cameras[0].size),
            "points": len(local), "in_process_seconds": t_local,
            "in_process_cpu_seconds": cpu_local, "in_process_workers": local.stats["workers"],
            "dask_seconds": t_tasks, "dask_client_cpu_seconds": cpu_client,
            "dask_workers_cpu_seconds_incl_startup": children_cpu() - children0,
            "dask_startup_seconds": t_up, "speedup": t_local / t_tasks,
            "load_before": load_before, "load_between": load_mid, "load_after": uptime(),
            "identical_points": all(same.values()), "identical": same}


def _square(x):
    return x * x


#: A fresh process: ``photosurf acquire``'s work on a folder (or only its imports and
#: kernel loading, the baseline), printing its peak RSS, time and cloud size as JSON.
_ACQUIRE_CHILD = r"""
import json, resource, sys, time
sys.path.insert(0, sys.argv[1])
import numpy as np
import matching.multiview, pipeline.engine
from matching.lsm import lsm_match
from matching.second_order import second_order_terms
from pipeline.acquisition import acquire_folder
image = np.random.default_rng(0).uniform(0, 255, (64, 64))
points = np.array([[32.0, 32.0], [30.0, 30.0]])
lsm_match(image, image, points, points)  # numba kernels loaded, as in any acquisition
second_order_terms(points, np.zeros((2, 6)))
def status_mib(key):
    for line in open("/proc/self/status"):
        if line.startswith(key + ":"):
            return int(line.split()[1]) / 1024
out = {"load_before": " ".join(open("/proc/loadavg").read().split()[:3]),
       "imports_peak_rss_mib": status_mib("VmHWM"), "rss_before_mib": status_mib("VmRSS")}
with open("/proc/self/clear_refs", "w") as f:
    f.write("5")  # reset the peak (VmHWM) to the current RSS: the acquisition's own peak
if sys.argv[2] != "imports":
    t, c = time.perf_counter(), time.process_time()
    cloud = acquire_folder(sys.argv[2])
    out.update(seconds=time.perf_counter() - t, cpu_seconds=time.process_time() - c,
               points=len(cloud), views=cloud.stats["views"], pairs=cloud.stats["pairs"],
               prepared_views=cloud.stats["prepared_views"],
               cloud_mib=sum(a.nbytes for a in (cloud.points, cloud.colours, cloud.sigma,
                                                cloud.views, cloud.pair)) / 2**20)
out["load_after"] = " ".join(open("/proc/loadavg").read().split()[:3])
out["peak_rss_mib"] = status_mib("VmHWM")
out["max_rss_process_mib"] = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
print(json.dumps(out))
"""


def _acquire_in_child(folder: str) -> dict:
    import subprocess

    done = subprocess.run([sys.executable, "-c", _ACQUIRE_CHILD, str(ROOT), folder],
                          capture_output=True, text=True, check=True)
    return json.loads(done.stdout.strip().splitlines()[-1])


def memory(workdir: Path, quick: bool) -> dict:
    """Peak RSS of ``photosurf acquire`` on a 24- and a 72-view ring, fresh processes.

    Each child imports photosurf and loads the numba kernels, resets its peak-RSS mark
    (``/proc/self/clear_refs``), runs the acquisition and reports the peak (``VmHWM``):
    ``beyond`` = peak - RSS before the acquisition - the final cloud's arrays.
    """
    from pipeline.scenes import load_recipe, render_scene

    small = ({"cameras": {"width": 256, "height": 192, "focal_px": 332.8},
              "shape": {"triangles": 20000}} if quick else {})
    base = _acquire_in_child("imports")
    runs = {}
    for n in (24, 72):
        folder = workdir / f"ring{n}" / "scene"
        if n == 24 and (workdir / "ring" / "scene").is_dir():
            folder = workdir / "ring" / "scene"  # the 24-view demo's own rendering
        else:
            recipe = load_recipe(ROOT / "fixtures" / "scenes" / "vase_ring.toml",
                                 {**small, "cameras": {**small.get("cameras", {}), "n": n}})
            render_scene(recipe, folder, progress=False)
        run = _acquire_in_child(str(folder))
        run["beyond_imports_and_cloud_mib"] = (run["peak_rss_mib"] - run["rss_before_mib"]
                                               - run["cloud_mib"])
        runs[str(n)] = run
    return {"imports_rss_mib": base["rss_before_mib"],
            "imports_peak_rss_mib": base["imports_peak_rss_mib"], "runs": runs}


def _print_runs(figures: dict, quick: bool) -> None:
    """The demo's and the stereo pair's stages: seconds and peak memory."""
    for key, title in (("demo", "Default demo = 24-view ring (make demo)"),
                       ("stereo_pair", "Stereo pair (one side only: stops after curves)")):
        if key not in figures:
            continue
        d = figures[key]
        print(f"{title} ({d['recipe']}{', quick: 256x192' if quick else ''}): "
              f"{d['total_seconds']:.2f} s (CPU {d['cpu_seconds']:.1f} s; load "
              f"{d['load_before']} -> {d['load_after']}), peak RSS so far "
              f"{d['peak_rss_mib']:.0f} MiB")
        print(f"  {'stage':<10} {'seconds':>9} {'peak MiB':>9}  status")
        for name, rec in d["stages"].items():
            secs = f"{rec['seconds']:.2f}" if rec.get("seconds") is not None else ""
            peak = f"{rec['peak_rss_mib']:.0f}" if rec.get("peak_rss_mib") is not None else ""
            note = f" ({rec['reason']})" if rec.get("reason") else ""
            print(f"  {name:<10} {secs:>9} {peak:>9}  {rec['status']}{note}")
        if key == "demo" and "scene_cached" in figures:
            c = figures["scene_cached"]
            print(f"  scene again from the cache: {c['stage_seconds']:.2f} s "
                  f"(rendered: {c['rendered_seconds']:.2f} s)")
        if d["error"]:
            print(f"  error: {d['error']}")
        print()


def _print_back_end(b: dict) -> None:
    """The demo's back end (smooth, export, report): its run and a rerun against the goal."""
    print(f"Demo back end ({b['patches']} patches, {b['triangles']} triangles exported; "
          f"load {b['load_before']} -> {b['load_after']})")
    print(f"  {'stage':<10} {'demo run s':>10} {'rerun s':>9}")
    for name in BACK_END:
        first, again = b["first_run"][name], b["rerun"][name]
        print(f"  {name:<10} {first if first is not None else float('nan'):10.2f} "
              f"{again if again is not None else float('nan'):9.2f}")
    print(f"  {'total':<10} {b['first_total']:10.2f} {b['rerun_total']:9.2f}")
    print(f"  goal smooth + export + report <= {BACK_END_GOAL_SECONDS:g} s: "
          f"{'met' if b['first_total'] <= BACK_END_GOAL_SECONDS else 'NOT met'} in the demo run "
          f"({b['first_total']:.1f} s), "
          f"{'met' if b['rerun_total'] <= BACK_END_GOAL_SECONDS else 'NOT met'} on the rerun "
          f"({b['rerun_total']:.1f} s)\n")


def _print_dask(p: dict, k: dict) -> None:
    """View pairs and a batch in process and on a Dask LocalCluster(2)."""
    print(f"{p['pairs']} view pairs of the {p['views']}-view ring "
          f"({p['image_size'][0]}x{p['image_size'][1]}, {p['points']} points), 2 cores")
    print(f"  {'executor':<28} {'seconds':>9} {'speed-up':>9}")
    print(f"  {'in-process (default)':<28} {p['in_process_seconds']:9.2f} {1.0:9.2f}"
          f"   CPU {p['in_process_cpu_seconds']:.1f} s on {p['in_process_workers']} threads "
          f"(numba kernels one thread each)")
    print(f"  {'Dask LocalCluster(2)':<28} {p['dask_seconds']:9.2f} {p['speedup']:9.2f}"
          f"   CPU client {p['dask_client_cpu_seconds']:.1f} s + workers "
          f"{p['dask_workers_cpu_seconds_incl_startup']:.1f} s (with start-up)")
    print(f"  (cluster start-up {p['dask_startup_seconds']:.1f} s; load {p['load_before']} -> "
          f"{p['load_between']} -> {p['load_after']}); identical to in-process: "
          f"{p['identical']}")
    print(f"  goal Dask LocalCluster(2) identical to the in-process default: "
          f"{'met' if p['identical_points'] else 'NOT met'}; speed-up {p['speedup']:.2f} "
          "(a figure, no goal; both use the 2 cores)\n")
    print(f"Batch of {k['objects']} objects ({k['points_per_object']} points each, cloud -> "
          f"export), {k['cpu_count']} cores")
    print(f"  {'executor':<28} {'seconds':>9} {'speed-up':>9}")
    print(f"  {'in-process (default)':<28} {k['in_process_seconds']:9.2f} {1.0:9.2f}")
    print(f"  {'Dask LocalCluster(2) tasks':<28} {k['dask_tasks_seconds']:9.2f} "
          f"{k['speedup_tasks']:9.2f}")
    print(f"  {'  + cluster start-up':<28} {k['dask_total_seconds']:9.2f} "
          f"{k['speedup_with_startup']:9.2f}")
    print(f"  identical outputs: {k['identical_outputs']}")


def _print_memory(m: dict) -> None:
    """Peak memory of photosurf acquire at 24 and 72 views."""
    print(f"\nPeak memory of photosurf acquire (fresh process; after imports + kernels "
          f"{m['imports_rss_mib']:.0f} MiB resident, {m['imports_peak_rss_mib']:.0f} MiB "
          "peak while importing)")
    print(f"  {'views':>5} {'pairs':>5} {'points':>8} {'peak MiB':>9} {'cloud MiB':>9} "
          f"{'beyond MiB':>10} {'seconds':>8} {'CPU s':>7}  load")
    for n, r in m["runs"].items():
        print(f"  {n:>5} {r['pairs']:>5} {r['points']:>8} {r['peak_rss_mib']:9.0f} "
              f"{r['cloud_mib']:9.1f} {r['beyond_imports_and_cloud_mib']:10.0f} "
              f"{r['seconds']:8.1f} {r['cpu_seconds']:7.1f}  {r['load_before']} -> "
              f"{r['load_after']}")
    r24, r72 = m["runs"]["24"], m["runs"]["72"]
    grows = r72["beyond_imports_and_cloud_mib"] / max(r24["beyond_imports_and_cloud_mib"], 1.0)
    # the working arrays of the pair points, fusion and outlier removal scale with the
    # points (a multiple of the cloud); what must not grow is the part per point
    per_point = ((r72["beyond_imports_and_cloud_mib"] / r72["points"])
                 / (r24["beyond_imports_and_cloud_mib"] / r24["points"]))
    print(f"  beyond imports and cloud, 72 vs 24 views: x{grows:.2f} in all, x{per_point:.2f} "
          f"per cloud point ({r72['points'] / r24['points']:.2f}x the points)")
    print(f"  goal memory bounded by streaming (per cloud point, 72 vs 24 views <= 1.25): "
          f"{'met' if per_point <= 1.25 else 'NOT met'}")


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--quick", action="store_true", help="small demo images, fewer objects")
    parser.add_argument("--json", default=str(ROOT / "benchmarks" / "results" / "pipeline.json"),
                        metavar="PATH", help="where to write the figures")
    parser.add_argument("--back-end", action="store_true",
                        help="only the demo and its back end (smooth, export, report)")
    args = parser.parse_args(argv)
    progress.set_quiet(True)
    workdir = Path(tempfile.mkdtemp(prefix="photosurf-bench-"))
    out = Path(args.json)
    out.parent.mkdir(parents=True, exist_ok=True)
    figures: dict = {}
    # a scene cache of this run's own: the demo renders its views as on a first run,
    # and the scene_cached step measures the copy a second run makes instead
    from pipeline import scene_cache

    os.environ[scene_cache.ENV] = str(workdir / "scene-cache")
    # the default demo is what ``make demo`` runs: the 24-view ring
    steps = [("demo", lambda: demo(workdir, "fixtures/scenes/vase_ring.toml", args.quick, "ring")),
             ("scene_cached", lambda: scene_cached(workdir, figures["demo"],
                                                   "fixtures/scenes/vase_ring.toml", "ring2")),
             ("back_end", lambda: back_end(workdir, figures["demo"],
                                           "fixtures/scenes/vase_ring.toml", "ring")),
             ("stereo_pair", lambda: demo(workdir, "fixtures/scenes/vase.toml", args.quick,
                                          "stereo")),
             ("dask_pairs", lambda: pair_speedup(workdir)),
             ("dask", lambda: dask_speedup(workdir, args.quick)),
             ("memory", lambda: memory(workdir, args.quick))]
    if args.back_end:
        steps = [steps[0], steps[2]]
    try:
        for key, step in steps:
            figures[key] = step()
            out.write_text(json.dumps(figures, indent=1) + "\n")  # keep what is measured
    finally:
        shutil.rmtree(workdir, ignore_errors=True)

    _print_runs(figures, args.quick)
    _print_back_end(figures["back_end"])
    if args.back_end:
        print(f"wrote {out}")
        return 0
    _print_dask(figures["dask_pairs"], figures["dask"])
    _print_memory(figures["memory"])
    print(f"\nwrote {out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
