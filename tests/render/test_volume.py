import drjit as dr
import mitsuba as mi
import numpy as np

from mitsnerf.fields.grid import GridField
from mitsnerf.math.camera import Camera, look_at
from mitsnerf.math.rays import camera_rays
from mitsnerf.render.volume import render_rays
from mitsnerf.math.box import UNIT_BOX


def _np(x):
    return np.asarray(x, dtype=np.float64)


def test_box_intersection_clips_rays_and_marks_misses():
    o = mi.Array3f([0.0, 0.0, 2.0, 0.0], [0.0, 0.3, 2.0, 0.0], [-2.0, -2.0, 0.0, 0.0])
    d = dr.normalize(mi.Array3f([0.0, 0.0, 0.0, 1.0], [0.0, 0.0, 1.0, 0.0], [1.0, 1.0, 0.0, 0.0]))
    t_n, t_f, hit = UNIT_BOX.intersect(o, d)
    np.testing.assert_allclose(_np(t_n), [1.5, 1.5, 0.0, 0.0], atol=1e-6)
    np.testing.assert_allclose(_np(t_f), [2.5, 2.5, 0.0, 0.5], atol=1e-6)
    assert list(np.asarray(hit)) == [True, True, False, True]


def test_homogeneous_box_through_the_renderer_matches_beer_lambert(each_variant):
    # sigma = 3 everywhere in the box; rays along z through the box have L = 1, diagonal ones longer.
    sigma = 3.0
    field = GridField.from_arrays(np.full((4, 4, 4), sigma, np.float32), UNIT_BOX, color=(1.0, 1.0, 1.0))
    o = mi.Array3f([0.0, 0.2], [0.0, -0.1], [-3.0, -3.0])
    d = dr.normalize(mi.Array3f([0.0, 0.0], [0.0, 0.0], [1.0, 1.0]))
    n = 32
    out = render_rays(field, o, d, n, u=dr.zeros(mi.Float, 2 * n), background=0.25, box=UNIT_BOX)
    np.testing.assert_allclose(_np(out.opacity), 1 - np.exp(-sigma * 1.0), rtol=1e-5)
    np.testing.assert_allclose(_np(out.rgb.x), (1 - np.exp(-sigma)) + 0.25 * np.exp(-sigma), rtol=1e-5)


def test_rays_missing_the_box_see_exactly_the_background():
    field = GridField.from_arrays(np.full((4, 4, 4), 50.0, np.float32), UNIT_BOX, color=(1.0, 0.0, 0.0))
    out = render_rays(field, mi.Array3f(2.0, 2.0, 2.0), mi.Array3f(0.0, 0.0, 1.0), 16,
                      background=lambda d: mi.Array3f(0.1, 0.2, 0.3), box=UNIT_BOX)
    np.testing.assert_allclose(np.array([_np(c)[0] for c in out.rgb]), [0.1, 0.2, 0.3], rtol=1e-6)
    assert _np(out.opacity)[0] == 0.0


def _parallel_misses():
    """Rays parallel to a face of the unit box, outside its slab: below and above it on each axis (the ray that
    made ngp's loss NaN at step 96 of paper's cloud, on LLVM and CUDA alike, was the first kind on z)."""
    o, d = [], []
    for axis in range(3):
        for side in (-0.6, 0.6):
            p, w = [0.0, 0.0, 0.0], [0.0, 0.0, 0.0]
            p[axis], p[(axis + 1) % 3], w[(axis + 1) % 3] = side, -2.0, 1.0
            o.append(p)
            d.append(w)
    return mi.Array3f(*np.array(o, np.float32).T), mi.Array3f(*np.array(d, np.float32).T)


def test_rays_parallel_to_a_face_outside_the_box_miss_with_a_finite_empty_interval():
    o, d = _parallel_misses()
    t_n, t_f, hit = UNIT_BOX.intersect(o, d)
    assert not np.any(np.asarray(hit))
    assert np.all(_np(t_n) == 0.0) and np.all(_np(t_f) == 0.0)
    t_n, t_f, hit = UNIT_BOX.intersect_numpy(np.array(o).T, np.array(d).T)
    assert not hit.any() and np.all(t_n == 0.0) and np.all(t_f == 0.0)


def test_rays_parallel_to_a_face_outside_the_box_see_the_background_and_give_finite_gradients():
    from mitsnerf.fields.ngp import NGPConfig, NGPField

    o, d = _parallel_misses()
    field = NGPField(NGPConfig(n_levels=2, hidden=8, color_hidden=8), mi.TensorXf, UNIT_BOX)
    dr.enable_grad(*field.params.values())
    out = render_rays(field, o, d, 8, u=dr.full(mi.Float, 0.5, 6 * 8), background=0.25, box=UNIT_BOX)
    np.testing.assert_array_equal(np.array([_np(c) for c in out.rgb]), 0.25)
    loss = dr.sum(out.rgb.x + out.rgb.y + out.rgb.z)
    dr.backward(loss)
    for key, value in field.params.items():
        assert np.all(np.isfinite(np.asarray(dr.grad(value)))), key


def test_midpoint_quadrature_error_is_first_order(blob_grid, each_variant):
    # The stratified quadrature covers [t_0, t_f]; with midpoints its optical-depth error is
    # -(h/2) sigma_t(t_f) (half an interval missing at the exit), so the error of the rendered
    # opacity of a homogeneous medium falls as 1/N: halving when N doubles.
    field = GridField.from_arrays(np.full((4, 4, 4), 2.0, np.float32), UNIT_BOX)
    o, d = mi.Array3f(0.0, 0.0, -2.0), mi.Array3f(0.0, 0.0, 1.0)
    exact = 1 - np.exp(-2.0)
    errors = [abs(_np(render_rays(field, o, d, n, box=UNIT_BOX).opacity)[0] - exact) for n in (4, 8, 16, 32, 64)]
    orders = np.log2(np.array(errors[:-1]) / np.array(errors[1:]))
    np.testing.assert_allclose(orders, 1.0, atol=0.1)


def test_camera_rays_through_a_blob_are_darker_at_its_projection(blob_grid):
    cam = Camera.from_fov(look_at((0.0, -2.0, 0.5)), 16, 12, 40.0)
    rays = camera_rays(mi.Array3f, [cam])
    out = render_rays(GridField.from_arrays(blob_grid, UNIT_BOX), rays.o, rays.d, 64, box=UNIT_BOX)
    opacity = _np(out.opacity).reshape(12, 16)
    row, col = np.unravel_index(np.argmax(opacity), opacity.shape)
    proj = cam.project(np.array([[0.1, 0.0, 0.0]]))[0]
    assert abs(col + 0.5 - proj[0]) <= 1.0 and abs(row + 0.5 - proj[1]) <= 1.0


def test_envmap_background_loads_with_one_drjit_thread(tmp_path):
    """Mitsuba's own EXR reader deadlocks after dr.set_thread_count(1) (bench --cpus-per-cell 1); the
    background reads the map itself. In a subprocess, so a regression fails on the timeout instead of hanging."""
    import subprocess
    import sys

    import numpy as np

    from mitsnerf.data.images import write_exr

    write_exr(tmp_path / "sky.exr", np.random.default_rng(0).uniform(0, 1, (8, 16, 3)).astype(np.float32))
    code = ("import mitsnerf, drjit as dr, mitsuba as mi; from mitsnerf import env; env.set_variant(); "
            "dr.set_thread_count(1); from mitsnerf.render.background import make_background; "
            f"bg = make_background({{'type': 'envmap', 'file': {str(tmp_path / 'sky.exr')!r}}}); "
            "print(bg(mi.Array3f(0, 0, 1)))")
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert done.returncode == 0 and done.stdout.strip().startswith("[["), done.stderr[-500:]
