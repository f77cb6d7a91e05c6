"""Benchmark of facetransfer.render against trimesh ray casting (issue 5, "Measured").

Frames per second on one core (NUMBA_NUM_THREADS=1) of

* ``rasterize``: depth + triangle id + barycentrics (fresh output arrays per frame);
* ``Rasterizer``: the same into reused buffers (what a tracker loop would use);
* ``vertex_visibility``: raster + per-vertex visibility (what the tracker calls per frame);
* ``render``: full colour frame, 1024x1024 UV texture, Lambert shading, visibility;

for face-like meshes of about 10,000 and 30,000 vertices (a spherical cap grid framed like a
face: 60 % of the frame height) at 640x480 and 1280x720, and, in the same run, the CPU
alternative a user might reach for: trimesh's ray casting (``trimesh.ray.ray_triangle``,
rtree + numpy, ``intersects_first`` for the triangle-id image, one orthographic ray per pixel
centre of the mesh's projected bounding box; rays outside the box are not cast, which favours
trimesh). The two triangle-id images are compared (agreement over pixels either covers).

    python benchmarks/bench_render.py [--out out/benchmarks] [--quick]

Writes ``OUT/render.json`` and ``OUT/render.png``.
"""

from __future__ import annotations

import os

os.environ.setdefault("NUMBA_NUM_THREADS", "1")
os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
os.environ.setdefault("MKL_NUM_THREADS", "1")

import argparse  # noqa: E402
import json  # noqa: E402
import platform  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402


def cap_mesh(n_side: int):
    """A face-like spherical cap grid of ``n_side**2`` vertices, CCW seen from +z, with UVs."""
    u = np.linspace(-1.2, 1.2, n_side)
    v = np.linspace(-1.2, 1.2, n_side)
    U, Vv = np.meshgrid(u, v)
    P = np.stack([np.sin(U) * np.cos(0.8 * Vv), 1.2 * np.sin(0.8 * Vv),
                  np.cos(U) * np.cos(0.8 * Vv)], -1).reshape(-1, 3)
    i = (np.arange(n_side - 1)[:, None] * n_side + np.arange(n_side - 1)[None]).ravel()
    F = np.concatenate([np.stack([i, i + 1, i + n_side + 1], 1),
                        np.stack([i, i + n_side + 1, i + n_side], 1)])
    uv = np.stack([(U.ravel() + 1.2) / 2.4, (Vv.ravel() + 1.2) / 2.4], 1)
    return P, F, uv


def timeit(fn, *, min_time: float = 1.0, max_reps: int = 400) -> dict:
    """Median and best wall seconds per call over repetitions filling ``min_time``, and the
    median CPU seconds of this thread (``time.thread_time``), which a busy shared machine
    inflates much less than wall time."""
    fn()  # warm-up (JIT load)
    times, cpu = [], []
    start = time.perf_counter()
    while (time.perf_counter() - start < min_time or len(times) < 3) and len(times) < max_reps:
        t, c = time.perf_counter(), time.thread_time()
        fn()
        cpu.append(time.thread_time() - c)
        times.append(time.perf_counter() - t)
    return {"median_s": float(np.median(times)), "best_s": float(np.min(times)),
            "cpu_median_s": float(np.median(cpu)), "reps": len(times),
            "fps": float(1.0 / np.median(times)), "fps_best": float(1.0 / np.min(times)),
            "fps_cpu": float(1.0 / max(np.median(cpu), 1e-9))}


def trimesh_ids(V, F, cam, size):
    """Triangle-id image by trimesh ray casting (orthographic rays, bounding box pixels)."""
    import trimesh
    from trimesh.ray.ray_triangle import RayMeshIntersector

    W, H = size
    Vc = cam.to_camera(V)  # rotated; orthographic rays along -z in camera space
    mesh = trimesh.Trimesh(Vc, F, process=False)
    xy = cam.project(V)
    x0, y0 = np.maximum(np.floor(xy.min(axis=0)).astype(int), 0)
    x1, y1 = np.minimum(np.ceil(xy.max(axis=0)).astype(int), [W - 1, H - 1])
    ys, xs = np.mgrid[y0:y1 + 1, x0:x1 + 1]
    px, py = xs.ravel().astype(float), ys.ravel().astype(float)
    # invert p = s diag(1,-1) Y + t
    ox = (px - cam.translation[0]) / cam.scale
    oy = -(py - cam.translation[1]) / cam.scale
    origins = np.stack([ox, oy, np.full_like(ox, Vc[:, 2].max() + 1.0)], 1)
    dirs = np.tile([0.0, 0.0, -1.0], (origins.shape[0], 1))
    t, c = time.perf_counter(), time.thread_time()
    inter = RayMeshIntersector(mesh)
    hit = inter.intersects_first(origins, dirs)
    elapsed, cpu = time.perf_counter() - t, time.thread_time() - c
    ids = np.full((H, W), -1, np.int64)
    ids[ys.ravel(), xs.ravel()] = hit
    return ids, elapsed, cpu, int(origins.shape[0])


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", default="out/benchmarks", help="output folder")
    ap.add_argument("--quick", action="store_true", help="shorter timings, 10k mesh only")
    args = ap.parse_args(argv)

    from facetransfer.io.atomic import save_figure, write_text_atomic
    from facetransfer.render import (Rasterizer, look_at_weak_perspective, rasterize, render,
                                     rotation_from_euler, vertex_visibility)

    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    rng = np.random.default_rng(0)
    tex = rng.integers(0, 256, (1024, 1024, 3), dtype=np.uint8)
    meshes = {"10k": 100} if args.quick else {"10k": 100, "30k": 173}
    sizes = [(640, 480), (1280, 720)]
    min_time = 0.5 if args.quick else 1.5
    rows = []
    for name, n_side in meshes.items():
        V, F, uv = cap_mesh(n_side)
        for size in sizes:
            R = rotation_from_euler(12.0, -6.0, 3.0)
            cam = look_at_weak_perspective(V, size, rotation=R, fill=0.6)
            rz = Rasterizer(size)
            r = rasterize(V, F, cam, size)
            row = {"mesh": name, "n_vertices": int(V.shape[0]), "n_faces": int(F.shape[0]),
                   "size": list(size), "covered_pixels": int(r.mask.sum())}
            row["rasterize"] = timeit(lambda: rasterize(V, F, cam, size), min_time=min_time)
            row["rasterizer_reuse"] = timeit(lambda: rz.rasterize(V, F, cam), min_time=min_time)
            row["visibility"] = timeit(lambda: vertex_visibility(V, F, cam, size),
                                       min_time=min_time)
            row["render_textured"] = timeit(
                lambda: render(V, F, cam, size, uvs=uv, texture=tex), min_time=min_time)
            ids, t_tm, c_tm, n_rays = trimesh_ids(V, F, cam, size)
            either = (ids >= 0) | r.mask
            row["trimesh_ray"] = {"seconds": t_tm, "cpu_seconds": c_tm, "fps": 1.0 / t_tm,
                                  "fps_cpu": 1.0 / c_tm, "rays": n_rays}
            row["agreement"] = float(np.mean(ids[either] == r.tri_id[either]))
            row["speedup_rasterize_vs_trimesh"] = row["rasterize"]["fps"] / row["trimesh_ray"]["fps"]
            row["speedup_rasterize_vs_trimesh_cpu"] = (row["rasterize"]["fps_cpu"]
                                                       / row["trimesh_ray"]["fps_cpu"])
            rows.append(row)
            print(f"{name:>4} {size[0]}x{size[1]}: rasterize {row['rasterize']['fps']:7.1f} fps "
                  f"(best {row['rasterize']['fps_best']:.0f}, cpu "
                  f"{row['rasterize']['fps_cpu']:.0f}), "
                  f"reuse {row['rasterizer_reuse']['fps']:7.1f}, visibility "
                  f"{row['visibility']['fps']:7.1f}, textured render "
                  f"{row['render_textured']['fps']:6.1f} (cpu "
                  f"{row['render_textured']['fps_cpu']:.0f}); trimesh rays "
                  f"{row['trimesh_ray']['fps']:.3f} fps ({n_rays} rays); ratio "
                  f"{row['speedup_rasterize_vs_trimesh']:.0f}x; id agreement "
                  f"{row['agreement']:.4f}", flush=True)

    import numba
    import trimesh

    load = os.getloadavg() if hasattr(os, "getloadavg") else None
    result = {"benchmark": "render", "threads": {"NUMBA_NUM_THREADS":
                                                  os.environ.get("NUMBA_NUM_THREADS")},
              "load_average_at_end": load,
              "note": "fps = 1 / median wall seconds per frame; fps_best = 1 / fastest frame; "
                      "fps_cpu = 1 / median CPU seconds of the thread; trimesh timed once "
                      "(index build + casting)",
              "machine": {"python": platform.python_version(), "cpu": platform.processor(),
                          "numpy": np.__version__, "numba": numba.__version__,
                          "trimesh": trimesh.__version__, "cores": os.cpu_count()},
              "peer": "trimesh.ray.ray_triangle.RayMeshIntersector.intersects_first",
              "rows": rows}
    write_text_atomic(out / "render.json", json.dumps(result, indent=2))

    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    labels = [f"{r['mesh']}\n{r['size'][0]}x{r['size'][1]}" for r in rows]
    keys = [("rasterize", "rasterize"), ("rasterizer_reuse", "Rasterizer (reuse)"),
            ("visibility", "visibility"), ("render_textured", "textured render"),
            ("trimesh_ray", "trimesh rays")]
    x = np.arange(len(rows))
    wbar = 0.16
    fig, ax = plt.subplots(figsize=(9, 4.5))
    for j, (k, lab) in enumerate(keys):
        vals = [r[k]["fps_cpu"] for r in rows]
        ax.bar(x + (j - 2) * wbar, vals, wbar, label=lab)
    ax.axhline(200, color="k", ls="--", lw=0.8, label="200 fps target")
    ax.set_yscale("log")
    ax.set_xticks(x, labels)
    ax.set_ylabel("frames per second of CPU time (one thread, log)")
    ax.set_title("facetransfer.render vs trimesh ray casting")
    ax.legend(fontsize=8, ncol=3)
    fig.tight_layout()
    save_figure(fig, out / "render.png", dpi=110)
    print(f"wrote {out / 'render.json'} and {out / 'render.png'}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
