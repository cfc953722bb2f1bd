"""Pose tracking from video: the silhouette renderer against a closed form and finite
differences, a one-frame track of a MuJoCo-rendered bunny from a perturbed pose, the
tracked poses as a trajectory, and bad input."""

import dataclasses
import json
from dataclasses import dataclass
import shutil

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

import dano
from dano.cli import main
from dano.errors import DanoError, FileFormatError
from dano.fields import SphereField
from dano.render import Cameras, image_rays, pixel_rays, project_points
from dano.render.silhouette import silhouette_rays
from dano.tracking import TrackConfig, TrackedObject, load_video, pose_errors, track, tracked_trajectory
from dano.experiments.slide import VideoCamera, render_video, surface_mesh, write_video_folder
from dano.trajectory import load_trajectory, save_trajectory

# a camera on the +y side looking at the origin from 3 m (Blender convention: looks along -z)
LOOK = np.array([[-1.0, 0.0, 0.0, 0.0], [0.0, 0.0, 1.0, 3.0], [0.0, 1.0, 0.0, 0.0], [0.0, 0.0, 0.0, 1.0]])


@pytest.fixture(scope="module")
def bunny():
    dano.enable_float64()
    return dano.load_builtin("bunny_lowpoly")


@pytest.fixture(scope="module")
def one_frame(bunny, tmp_path_factory):
    """One 320x240 MuJoCo render of the low-poly bunny's surface (its field's d = 0), tipped and turned."""
    quat = Rotation.from_rotvec([0.3, -0.2, 0.9]).as_quat(scalar_first=True)
    pose = np.r_[0.1, 0.05, 0.4, quat]
    camera = VideoCamera(lookat=(0.1, 0.05, 0.3), distance=2.6)
    frames, masks, background, c2w, focal = render_video(bunny, pose[None], camera, mesh=surface_mesh(bunny))
    folder = write_video_folder(tmp_path_factory.mktemp("video") / "one", frames, masks, background, c2w, focal,
                                fps=50.0)
    return folder, pose


def test_sphere_silhouette_area_matches_projection():
    """A sphere of radius R at distance Z covers π(f·R/√(Z² − R²))² pixels: the coverage α
    summed over the image gives it (the edge sits on the surface: no outward bias)."""
    dano.enable_float64()
    R, Z, f, n = 0.5, 3.0, 80.0, 96
    cams = Cameras.create(LOOK[None], n, n, f, dtype=jnp.float64)
    o, d = image_rays(cams, 0)
    alpha = silhouette_rays(SphereField(radius=R, edge_width=0.01), o, d, step=0.01, num_samples=120,
                            pixel_angle=1.0 / f).alpha
    expected = np.pi * (f * R / np.sqrt(Z * Z - R * R)) ** 2
    assert float(alpha.sum()) == pytest.approx(expected, rel=0.01)
    assert float(alpha.min()) >= 0 and float(alpha.max()) <= 1


def test_a_ray_missing_the_box_covers_nothing():
    """Rays that pass the sphere's box, one almost parallel to its top face (its slab crossing
    1.5e5 m away: α was 0.31 there), cover 0 of their pixels; a grazing ray beside the sphere
    covers a part, as before."""
    dano.enable_float64()
    o = jnp.asarray([[-3.0, 0.0, 2.0], [-3.0, 0.0, 0.0], [-3.0, 0.0, 0.0]])
    d = jnp.asarray([[1.0, 0.0, -1e-5], [0.0, 1.0, 0.0], [1.0, 0.5 / 3.0, 0.0]])
    d = d / jnp.linalg.norm(d, axis=1, keepdims=True)
    out = silhouette_rays(SphereField(radius=0.5, edge_width=0.01), o, d, step=0.01, num_samples=120,
                          pixel_angle=1.0 / 30.0)
    np.testing.assert_array_equal(np.asarray(out.alpha[:2]), 0.0)
    assert 0.2 < float(out.alpha[2]) < 0.8


def test_field_silhouette_matches_mujoco_mask_at_the_true_pose(bunny, one_frame):
    """The silhouette dano renders of the field and MuJoCo's mask of its surface mesh cover
    the same pixels at the true pose (area within 0.5 %, barycentre within 0.1 px): no
    bias for the tracker to absorb (the asset's coarse visual mesh gave +1.3 to +2.0 %)."""
    folder, pose = one_frame
    video = load_video(folder)
    obj = TrackedObject.from_asset(bunny)
    h, w = video.masks.shape[1:]
    v, u = np.meshgrid(np.arange(h) + 0.5, np.arange(w) + 0.5, indexing="ij")
    uv = np.stack([u.ravel(), v.ravel()], -1)
    o, d = pixel_rays(video.camera, jnp.zeros(len(uv), jnp.int32), jnp.asarray(uv[:, 0]), jnp.asarray(uv[:, 1]))
    R = Rotation.from_quat(pose[3:], scalar_first=True).as_matrix()
    b = np.asarray(bunny.field.bounds())
    alpha = np.asarray(silhouette_rays(bunny.field, o, d, pose=(jnp.asarray(pose[:3] - R @ obj.center_of_mass),
                                                                jnp.asarray(pose[3:])),
                                       step=float(np.linalg.norm(b[1] - b[0])) / 96, num_samples=98,
                                       pixel_angle=1.0 / float(video.camera.focal[0, 0])).alpha)
    mask = video.masks[0].ravel()
    assert alpha.sum() / mask.sum() == pytest.approx(1.0, abs=0.005)
    bary = lambda a: (a[:, None] * uv).sum(0) / a.sum()  # noqa: E731
    assert np.abs(bary(alpha) - bary(mask)).max() < 0.1


@pytest.mark.parametrize("convention", ["blender", "opencv"])
def test_project_points_inverts_pixel_rays(convention):
    """A point 2.5 m along the ray through pixel (u, v) projects back to (u, v) at the depth
    its ray gives; the camera's own position mirrored through it lies behind (depth < 0)."""
    cams = Cameras.create(LOOK[None], 64, 48, (70.0, 60.0), (30.0, 25.0), convention=convention,
                          dtype=jnp.float64)
    u, v = np.array([0.5, 31.25, 63.5]), np.array([0.5, 20.0, 47.5])
    o, d = (np.asarray(x) for x in pixel_rays(cams, jnp.zeros(3, jnp.int32), jnp.asarray(u), jnp.asarray(v)))
    uv, depth = project_points(cams, 0, o + 2.5 * d)
    np.testing.assert_allclose(uv, np.stack([u, v], -1), atol=1e-9)
    axis = LOOK[:3, 2] * (-1.0 if convention == "blender" else 1.0)  # the optical axis in the world
    np.testing.assert_allclose(depth, 2.5 * d @ axis, rtol=1e-12)
    assert project_points(cams, 0, o - 2.5 * d)[1].max() < 0


def test_silhouette_pose_gradient_matches_finite_differences(bunny):
    """d(Σ α·weights)/d(position, quaternion) by forward-mode AD equals central differences."""
    cams = Cameras.create(LOOK[None], 48, 48, 30.0, dtype=jnp.float64)
    o, d = image_rays(cams, 0)
    w = jnp.asarray(np.random.default_rng(0).uniform(0.5, 1.5, len(o)))
    field = bunny.field

    def f(x):
        a = silhouette_rays(field, o, d, pose=(x[:3], x[3:]), step=0.015, num_samples=110,
                            pixel_angle=1.0 / 30.0).alpha
        return jnp.sum(a * w)

    f = jax.jit(f)
    x0 = jnp.asarray(np.r_[0.02, -0.03, 0.01, 0.98, 0.1, -0.15, 0.05])
    ad = np.asarray(jax.jit(jax.jacfwd(f))(x0))
    h = 1e-6
    fd = np.array([(float(f(x0.at[i].add(h))) - float(f(x0.at[i].add(-h)))) / (2 * h) for i in range(7)])
    assert np.all(np.isfinite(ad))
    np.testing.assert_allclose(ad, fd, rtol=2e-3, atol=2e-3 * np.abs(fd).max())


@pytest.fixture(scope="module")
def perturbed_track(bunny, one_frame):
    """The one frame tracked with the default settings from a pose off by 3 cm and 20 degrees:
    (start pose, result). Shared by the tests of the track and of its trajectory (one
    compilation of the per-frame solve)."""
    folder, truth = one_frame
    video = load_video(folder)
    start = truth.copy()
    start[:3] += [0.02, -0.015, 0.015]
    start[3:] = (Rotation.from_quat(truth[3:], scalar_first=True)
                 * Rotation.from_rotvec(np.radians(20.0) * np.array([0.6, 0.0, 0.8]))).as_quat(scalar_first=True)
    return start, track(video, TrackedObject.from_asset(bunny), start, TrackConfig())


def test_one_frame_track_converges_from_a_perturbed_pose(bunny, one_frame, perturbed_track):
    """Tracking one MuJoCo-rendered frame (the renderer dano does not use) from a pose off by
    3 cm and 20 degrees succeeds by the tracking issue's measure (within 2 % of the bunny's
    size and 5 degrees); the rotation ends within 1.5 degrees."""
    _, truth = one_frame
    start, result = perturbed_track
    before = pose_errors(start[None], truth[None])
    dp, dr = pose_errors(result.poses, truth[None])
    size = float(np.linalg.norm(np.ptp(bunny.mesh_vertices, axis=0)))
    assert dp[0] < 0.02 * size and dr[0] < 1.5 < before[1][0], (dp, dr, before)
    assert result.iou[0] > 0.9 and not result.poor[0]


def test_a_cold_start_is_solved_again_until_the_loss_stops_falling(bunny, one_frame, perturbed_track):
    """A frame that starts from no prediction (here the first, from the user's pose 20 degrees off) gets
    further Adam runs from its own result while the loss falls by 1 % or more: they end
    nearer the truth than one run, and the runs are counted in the summary."""
    folder, truth = one_frame
    start, again = perturbed_track
    once = track(load_video(folder), TrackedObject.from_asset(bunny), start, TrackConfig(cold_start_passes=1))
    assert once.cold_start_passes == (1,) and 2 <= again.cold_start_passes[0] <= 5
    assert again.summary()["cold_start_passes"] == list(again.cold_start_passes)
    (d1, r1), (d2, r2) = pose_errors(once.poses, truth[None]), pose_errors(again.poses, truth[None])
    assert again.loss[0] < once.loss[0] and d2[0] < d1[0] and r2[0] < r1[0]
    with pytest.raises(DanoError, match="cold_start_passes must be at least 1"):
        TrackConfig(cold_start_passes=0)


def test_tracked_poses_are_a_trajectory(perturbed_track, tmp_path):
    _, result = perturbed_track
    traj = tracked_trajectory(result, "bunny")
    path = save_trajectory(traj, tmp_path / "poses.npz")
    back = load_trajectory(path)
    assert back.dano_names == ("bunny",) and back.qpos.shape == (1, 7)
    np.testing.assert_allclose(back.dano_pose("bunny")[0], result.poses[:, :3])


def test_background_subtraction_finds_the_rendered_object(one_frame):
    folder, _ = one_frame
    given = load_video(folder).masks
    subtracted = load_video(folder, subtract_background=True).masks
    iou = np.minimum(given, subtracted).sum() / np.maximum(given, subtracted).sum()
    assert iou > 0.93


def _copy(folder, tmp_path):
    target = tmp_path / "video"
    shutil.copytree(folder, target)
    return target


def test_bad_video_inputs_are_refused_clearly(one_frame, tmp_path):
    folder, truth = one_frame
    empty = tmp_path / "empty"
    (empty / "frames").mkdir(parents=True)
    shutil.copy(folder / "camera.json", empty / "camera.json")
    with pytest.raises(FileFormatError, match="no frames"):
        load_video(empty)
    mixed = _copy(folder, tmp_path / "mixed")
    import imageio.v3 as iio

    iio.imwrite(mixed / "frames" / "0001.png", np.zeros((10, 12, 3), np.uint8))
    with pytest.raises(FileFormatError, match="one size"):
        load_video(mixed)
    wrong = _copy(folder, tmp_path / "wrong")
    meta = json.loads((wrong / "camera.json").read_text())
    (wrong / "camera.json").write_text(json.dumps({**meta, "w": 640}))
    with pytest.raises(FileFormatError, match="frames are 320x240"):
        load_video(wrong)
    nan = _copy(folder, tmp_path / "nan")
    (nan / "camera.json").write_text(json.dumps({**meta, "fl_x": float("nan")}).replace("NaN", "NaN"))
    with pytest.raises((FileFormatError, DanoError), match="focal"):
        load_video(nan)
    with pytest.raises(DanoError, match="no frames to track"):
        track(load_video(folder), TrackedObject(SphereField(radius=0.1), np.zeros(3), 0.2), truth, frames=slice(5, 5))
    with pytest.raises(DanoError, match="initial pose"):
        track(load_video(folder), TrackedObject(SphereField(radius=0.1), np.zeros(3), 0.2), [0, 0, 0, 0, 0, 0, 0])


def test_track_cli_refuses_bad_input_and_leaves_nothing(one_frame, tmp_path, capsys):
    folder, truth = one_frame
    empty = tmp_path / "frames"
    empty.mkdir()
    out = tmp_path / "out"
    pose = [str(x) for x in truth]
    code = main(["track", str(empty), "--object", "builtin:bunny_lowpoly", "--pose", *pose, "-o", str(out),
                 "--camera", str(folder / "camera.json"), "--quiet"])
    err = capsys.readouterr().err
    assert code == 1 and "no frames" in err and "Traceback" not in err
    assert not out.exists()
    code = main(["track", str(folder), "--object", "builtin:bunny_lowpoly", "--pose", *pose[:6], "-o", str(out)])
    assert code != 0 and not out.exists()
    capsys.readouterr()
    # the pose 5 m to the side: outside the image (it would track at IoU 0, every frame poor)
    aside = [str(truth[0] + 5.0), *pose[1:]]
    code = main(["track", str(folder), "--object", "builtin:bunny_lowpoly", "--pose", *aside, "-o", str(out),
                 "--quiet"])
    err = capsys.readouterr().err
    assert code == 1 and "not in view in the first frame tracked" in err and "of the 320x240 image" in err
    assert "Traceback" not in err and not out.exists()
    # --identify needs motion: a one-frame video is refused before tracking, naming the video
    code = main(["track", str(folder), "--object", "builtin:bunny_lowpoly", "--pose", *pose, "-o", str(out),
                 "--identify", "--quiet"])
    err = " ".join(capsys.readouterr().err.split())
    assert code == 1 and "--identify needs at least 8 frames" in err and "has 1" in err and not out.exists()
    from dano.tracking.outputs import poor_frames_warning

    assert poor_frames_warning({"frames": 61, "poor_frames": 0}) == []
    assert "3 of the 61 tracked frames are flagged poor" in poor_frames_warning({"frames": 61, "poor_frames": 3})[0]


@jax.tree_util.register_dataclass
@dataclass(frozen=True)
class _Painted:
    """The bunny's field as a radiance field of one colour (extinction 40/m inside)."""

    field: object
    colour: jax.Array

    def bounds(self):
        return self.field.bounds()

    def density(self, points):
        return self.field.density(points)

    def radiance(self, points, directions):
        sigma = 40.0 * self.field.density(points) / self.field.interior_density()
        return sigma, jnp.broadcast_to(self.colour, points.shape)


@pytest.fixture(scope="module")
def painted_frame(bunny, one_frame):
    """The one frame's view (a half-size camera) of the bunny painted one colour, rendered by
    dano's volume renderer over the MuJoCo background: (video, true pose, painted field).
    Shared by both colour-term tests (one render)."""
    from dano.render import RenderOptions, render_rays
    from dano.tracking.track import field_pose

    folder, _ = one_frame
    video = load_video(folder)
    quat = np.array([0.95, 0.1, -0.1, 0.27])
    truth = np.r_[0.1, 0.05, 0.4, quat / np.linalg.norm(quat)]
    painted = _Painted(dataclasses.replace(bunny.field, edge_width=0.012), jnp.asarray([0.72, 0.55, 0.38]))
    config = TrackConfig(colour_weight=1.0, stride=2, iterations=40)
    b = np.asarray(bunny.field.bounds())
    options = RenderOptions(float(np.linalg.norm(b[1] - b[0])) / config.samples_across, config.samples_across + 2)
    pose = field_pose(jnp.asarray(truth[:3]), jnp.asarray(truth[3:]),
                      jnp.asarray(TrackedObject.from_asset(bunny).center_of_mass))
    # a half-size camera (same view): a quarter of the rays to render
    c = video.camera
    camera = Cameras.create(np.asarray(c.camera_to_world), c.width // 2, c.height // 2, np.asarray(c.focal[0]) / 2,
                            np.asarray(c.principal[0]) / 2, dtype=jnp.float64)
    background = video.background[::2, ::2]
    origins, directions = image_rays(camera, 0)
    image = jax.jit(lambda o, d, bg: render_rays(painted, o, d, options, pose=pose, background=bg).rgb)(
        origins, directions, jnp.asarray(background.reshape(-1, 3)))
    video = dataclasses.replace(video, frames=np.asarray(image).reshape(1, *background.shape).astype(np.float32),
                                masks=None, camera=camera, background=background)
    return video, truth, painted


@pytest.mark.parametrize("occupancy", [False, True])
def test_colour_term_tracks_with_a_radiance_field(bunny, painted_frame, occupancy):
    """Photometric tracking alone (no masks: the robust colour term through the volume
    renderer) converges from a perturbed pose to the pose that rendered the frame, within the
    success measure (2 % of size, 5 degrees). The frame is rendered by dano's own volume
    renderer from the same radiance field (a soft one-colour bunny over the MuJoCo
    background): a check of the method's machinery, not of its accuracy on real shading.
    The colour term uses 1024 of the rays; with an occupancy grid, only occupied samples
    within a budget of 32 per ray."""
    video, truth, painted = painted_frame
    grid = None
    if occupancy:
        from dano.render import OccupancyGrid

        grid = OccupancyGrid.create(painted.bounds(), 32, threshold=0.5)
        sigma = painted.radiance(grid.cell_centres(), jnp.zeros((32 ** 3, 3)))[0].reshape(32, 32, 32)
        grid = dataclasses.replace(grid, density=sigma.astype(grid.density.dtype))
    obj = TrackedObject.from_asset(bunny, radiance=painted, radiance_occupancy=grid)
    config = TrackConfig(colour_weight=1.0, stride=2, iterations=40)
    start = truth.copy()
    start[:3] += [0.02, 0.01, -0.01]
    result = track(video, obj, start, config)
    dp, dr = pose_errors(result.poses, truth[None])
    size = float(np.linalg.norm(np.ptp(bunny.mesh_vertices, axis=0)))
    assert np.all(np.isfinite(result.poses)) and np.isfinite(result.loss[0])
    assert dp[0] < 0.02 * size and dr[0] < 5.0, (dp, dr)
    with pytest.raises(DanoError, match="radiance"):
        track(video, TrackedObject.from_asset(bunny), start, TrackConfig(colour_weight=0.1))


@pytest.mark.slow
def test_pixel_fit_uses_the_identification_solver(tmp_path, monkeypatch):
    """identify_from_pixels on a 6-frame, 160x120 synthetic slide: its local solve is
    identification's (dano.sysid.solve.solve_least_squares), started from the scan's best
    point; the answer costs no more than any scanned point; the result keeps its keys."""
    from dano.experiments.slide import VideoCamera, slide_trajectory, synthetic_slide
    from dano.sysid import solve
    from dano.tracking import pixels

    calls = []

    def spy(*args, **kwargs):
        calls.append((np.array(args[1]), solve.solve_least_squares(*args, **kwargs)))
        return calls[-1][1]

    monkeypatch.setattr(pixels, "solve_least_squares", spy)
    folder = synthetic_slide(tmp_path / "slide", duration=0.1, camera=VideoCamera(width=160, height=120))
    scene, truth = slide_trajectory(duration=0.1)
    ticks = []
    result = pixels.identify_from_pixels(scene, scene.default_params(), load_video(folder),
                                         TrackedObject.from_asset(scene.assets[0]), np.asarray(truth.qpos[0]),
                                         np.asarray(truth.qvel[0]), substeps=2, scan=3, stride=8, max_iterations=4,
                                         progress=lambda k, n, what: ticks.append(what))
    (x0, fit), = calls
    values, costs = result.scan["values"], result.scan["costs"]
    assert len(values) == 6 and x0[0] == values[int(np.argmin(costs))]
    np.testing.assert_array_equal(result.estimates, fit.x)
    assert result.cost == fit.cost <= costs.min() and result.nfev == fit.nfev <= 4
    assert len(ticks) == 6 + result.nfev
    assert set(result.as_dict()) == {"parameters", "cost", "scan", "nfev", "njev", "wall_time_s", "compile_time_s",
                                     "success", "message"}
    assert list(result.as_dict()["parameters"]) == ["sliding_friction", "dx", "dy", "dz", "vx", "vy", "vz", "wx",
                                                    "wy", "wz"]


def _mujoco_slide_video(tmp_path, shared, hidden=()):
    """The low-poly bunny (0.2 m, 0.7 kg) slid in plain MuJoCo C (friction 0.5), 41 frames at
    50 Hz rendered by MuJoCo, the object's left half hidden behind the background's colour in
    the ``hidden`` frames: (video folder, the .dano, MuJoCo's poses (41, 7))."""
    from dano.experiments.mujoco_c import mujoco_c_slides

    made = mujoco_c_slides(tmp_path / "made", mesh=str(shared / "meshes" / "bunny_lowpoly.obj"), slides=1,
                           rate=50.0, duration=0.8, friction=0.5, seed=1)
    poses = np.loadtxt(made["csv"][0], delimiter=",", skiprows=1)[:, 1:8]
    asset = dano.load(made["dano"])
    mid = 0.5 * (poses[0, :3] + poses[-1, :3])
    camera = VideoCamera(lookat=(mid[0], mid[1], 0.05), distance=0.6, azimuth=-60.0, elevation=-35.0)
    frames, masks, background, c2w, focal = render_video(asset, poses, camera, mesh=surface_mesh(asset))
    frames = np.array(frames)
    for i in hidden:
        left = np.arange(frames.shape[2]) < np.median(np.nonzero(masks[i] > 0.5)[1])
        frames[i][:, left] = np.asarray(background)[:, left]
    folder = write_video_folder(tmp_path / "video", frames, masks, background, c2w, focal, fps=50.0)
    return folder, made["dano"], poses


def _track_identify(folder, asset, poses, out, capsys) -> dict:
    """``dano track --identify --json`` from a start 8 mm off MuJoCo's first pose: the report."""
    start = poses[0] + np.r_[0.005, -0.005, 0.003, 0, 0, 0, 0]
    code = main(["track", str(folder), "--object", str(asset), "--pose", *map(str, start), "-o", str(out),
                 "--subtract-background", "--no-video", "--identify", "--quiet", "--json"])
    cap = capsys.readouterr()
    assert code == 0, cap.err
    return json.loads(cap.out)


@pytest.mark.slow
def test_track_identify_on_a_slide_made_by_plain_mujoco(tmp_path, shared, capsys):
    """A user's own video, made without dano's physics: the low-poly bunny (0.2 m, 0.7 kg)
    slides in plain MuJoCo C (friction 0.5), MuJoCo renders 41 frames at 50 Hz, and
    `dano track --identify` with its defaults (masks by background subtraction, a start 8 mm
    off) tracks it and identifies the friction: the tracked poses within 5 mm RMS of
    MuJoCo's, the 95 % interval covering 0.5 and narrower than ±0.1 (measured 2026-11-26:
    1.9 mm; 0.497 [0.446, 0.547])."""
    folder, asset, poses = _mujoco_slide_video(tmp_path, shared)
    out = tmp_path / "tracked"
    report = _track_identify(folder, asset, poses, out, capsys)
    dp, _ = pose_errors(load_trajectory(out / "poses.npz").qpos[:, :7], poses)
    assert np.sqrt(np.mean(dp ** 2)) < 0.005, dp
    found = report["identification"]
    lower, upper = found["sliding_friction_lower"], found["sliding_friction_upper"]
    assert lower < 0.5 < upper and upper - lower < 0.2, found
    assert json.loads((out / "sysid" / "result.json").read_text())["sliding_friction"] == found["sliding_friction"]
    assert (out / "problem.toml").is_file() and (out / "sysid" / "fit.png").is_file()


@pytest.mark.slow
def test_track_identify_leaves_out_frames_something_hid(tmp_path, shared, capsys):
    """The same MuJoCo video with the bunny's left half hidden in 5 frames (an occluder the
    background's colour): the tracker loses those frames (measured 2026-11-27: 59-318 mm off)
    and flags them poor; the identification leaves them out as missing frames and covers 0.5
    (0.4865 [0.4468, 0.5297]), where keeping them (skip_poor_frames = false) gave no finite
    start of the scan at all."""
    hidden = [10, 11, 12, 20, 21]
    folder, asset, poses = _mujoco_slide_video(tmp_path, shared, hidden)
    out = tmp_path / "tracked"
    report = _track_identify(folder, asset, poses, out, capsys)
    poor = load_trajectory(out / "poses.npz").metadata["poor_frames"]
    assert set(poor) >= {11, 12, 20, 21} and len(poor) <= 7, poor
    found = report["identification"]
    assert found["sliding_friction_lower"] < 0.5 < found["sliding_friction_upper"], found
    assert any("flagged poor" in w and "leaves them out" in w for w in found["warnings"]), found["warnings"]
    assert any("frames missing" in n for n in found["notes"]), found["notes"]


@pytest.mark.slow
def test_the_tracked_route_keeps_the_friction_of_a_slide_tracked_with_cm_errors(tmp_path, shared, capsys):
    """A new user's mallet, slid in plain MuJoCo C at friction 0.4 and tracked by `dano track`
    with 11 mm RMS errors (mostly along the camera's axis): the problem `--identify` wrote then
    (windows of 10 frame intervals, each start velocity fitted) gave 0.053 [0, 0.576]; single
    shooting 0.408. Here a MuJoCo C slide of the low-poly bunny (0.12 m, 0.3 kg, friction 0.4,
    100 Hz) with errors of that kind (10 mm along one oblique axis, 1 mm across, 1°) goes
    through the problem `dano track --identify` writes: within 5 % of 0.4 (measured
    2026-11-28: 0.404 [0.3945, 0.4141]; the windows' route gave 0.606 [0.542, 0.667])."""
    from dano.experiments.mujoco_c import mujoco_c_slides
    from dano.pose import quat_multiply, rotvec_to_quat
    from dano.trajectory import Trajectory
    from dano.tracking.outputs import write_tracked_problem

    made = mujoco_c_slides(tmp_path / "made", mesh=str(shared / "meshes" / "bunny_lowpoly.obj"), size=0.12, mass=0.3,
                           slides=1, rate=100.0, duration=0.6, friction=0.4, seed=1)
    rows = np.loadtxt(made["csv"][0], delimiter=",", skiprows=1)
    t, q = rows[:, 0], rows[:, 1:8].copy()
    rng = np.random.default_rng(1)
    axis = np.array([0.6, -0.5, -0.62]) / np.linalg.norm([0.6, -0.5, -0.62])  # a camera's viewing direction
    q[:, :3] += rng.normal(0, 0.01, (len(t), 1)) * axis + rng.normal(0, 0.001, (len(t), 3))
    q[:, 3:] = np.asarray(quat_multiply(q[:, 3:], rotvec_to_quat(rng.normal(0, np.radians(1.0), (len(t), 3)))))
    name = dano.load(made["dano"]).name
    save_trajectory(Trajectory(t, q, np.zeros((len(t), 6)), np.zeros((len(t), 0)), (name,), (name,), (0,), (0,), (),
                               {"source": "dano track", "poor_frames": []}), tmp_path / "poses.npz")
    toml = write_tracked_problem(tmp_path, str(made["dano"]), 0.01)
    assert main(["sysid", str(toml), "--json", "-o", str(tmp_path / "sysid")]) == 0
    found = json.loads(capsys.readouterr().out)
    assert abs(found["sliding_friction"] - 0.4) < 0.02, found["sliding_friction"]
    assert found["sliding_friction_lower"] < found["sliding_friction"] < found["sliding_friction_upper"]
