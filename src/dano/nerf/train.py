"""Training a :class:`~dano.nerf.HashGridField` from posed images.

Each step draws ``rays_per_step`` random pixels of the training views, renders them with
the occupancy grid skipping empty space (:func:`dano.render.render_rays`, a fixed budget of
field evaluations) and takes an Adam step (optax) on the mean squared colour error (plus,
optionally, the squared alpha error against the images' masks). The learning rate decays
log-linearly from ``learning_rate`` to ``final_learning_rate`` over the run (by steps or by
the clock, whichever ends it). The occupancy grid is refreshed every ``occupancy_every``
steps. The clock counts training only: it starts after the step's program is compiled (or
loaded), and leaves out evaluation and checkpoint writing.
"""

from __future__ import annotations

import csv
import dataclasses
import io
import json
import math
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Annotated, Callable

import jax
import jax.numpy as jnp
import numpy as np
import optax
import tyro

from .._files import atomic_write, config_json
from ..errors import DanoError
from ..render.cameras import pixel_rays
from ..render.volume import OccupancyGrid, RenderConfig, psnr, render_image, render_rays, update_occupancy
from .checkpoint import load_field, load_optimizer_state, save_field
from .data import Dataset, load_dataset
from .field import FieldConfig, HashGridField
from ..viz.plot import plot_heldout

BACKGROUNDS = ("white", "black", "random")


@dataclass(frozen=True)
class TrainConfig:
    """How a field is trained (saved as ``config.json`` beside every trained field). Raises
    DanoError naming the option for values that cannot train; :meth:`check_data` checks it
    against a dataset."""

    minutes: float = 3.0
    """Training time [min] (compiling before it and evaluation excluded)."""
    steps: int = 0
    """Stop after this many steps (0: only the clock stops training)."""
    rays_per_step: int = 4096
    """Rays (pixels) drawn per Adam step; those whose samples do not fit the budget are left out."""
    samples_per_ray: int = 12
    """Field evaluations per step = rays_per_step times this (the packed budget)."""
    samples_across: int = 256
    """Sample spacing = the box diagonal / this."""
    learning_rate: float = 1e-2
    """Adam's initial learning rate."""
    final_learning_rate: float = 3e-4
    """Learning rate at the end of the run (log-linear decay)."""
    holdout: int = 10
    """Views held out for evaluation (evenly spread over the set)."""
    background: str = "white"
    """Background behind the object: white, black or random (random needs RGBA images)."""
    mask_weight: float = 0.0
    """Weight of the alpha (mask) loss; needs RGBA images."""
    occupancy_resolution: int = 64
    """Cells across the box of the occupancy grid."""
    occupancy_every: int = 16
    """Steps between occupancy-grid refreshes."""
    occupancy_alpha: float = 0.01
    """A cell is empty when its opacity per sample step stays below this."""
    carve: bool = True
    """Start the occupancy grid from the images: cells seen as background in any view stay empty
    (alpha masks, or the plain white/black background of RGB images)."""
    eval_at_minutes: tuple[float, ...] = ()
    """Also measure held-out PSNR when the clock passes these minutes."""
    checkpoint_minutes: float = 2.0
    """Minutes between checkpoints (and one at the end)."""
    seed: int = 0
    """Random seed (initial parameters, rays, jitter)."""
    field: FieldConfig = dataclasses.field(default_factory=FieldConfig)
    """Architecture of the hash-grid field."""

    def __post_init__(self):
        if not (self.minutes > 0 and math.isfinite(self.minutes)):
            raise DanoError(f"--minutes must be a positive number, got {self.minutes}")
        for name in ("rays_per_step", "samples_per_ray", "samples_across", "occupancy_resolution", "occupancy_every"):
            if getattr(self, name) < 1:
                raise DanoError(f"--{name.replace('_', '-')} must be >= 1, got {getattr(self, name)}")
        if self.steps < 0:
            raise DanoError(f"--steps must be >= 0, got {self.steps}")
        if not (0 < self.final_learning_rate <= self.learning_rate):
            raise DanoError("learning rates must satisfy 0 < final-learning-rate <= learning-rate")
        if self.background not in BACKGROUNDS:
            raise DanoError(f"--background must be one of {BACKGROUNDS}, got {self.background!r}")

    def check_data(self, data: Dataset) -> "TrainConfig":
        """Returns self; raises DanoError if ``data`` cannot be trained on with these
        settings (a random background or a mask loss without alpha masks)."""
        if data.alpha is None and (self.background == "random" or self.mask_weight > 0):
            raise DanoError(f"{data.source}: --background random and --mask-weight need RGBA images (alpha masks)")
        return self

    def check(self, data: Dataset | None = None) -> "TrainConfig":
        """Old API, kept: the settings are checked when the config is built; with ``data``,
        :meth:`check_data`. Returns self."""
        return self if data is None else self.check_data(data)


@dataclass
class TrainResult:
    """What :func:`train` returns: the field, its occupancy grid, and the run's record."""

    field: HashGridField
    occupancy: OccupancyGrid
    steps: int
    wall_time_s: float
    rays_per_s: float
    psnr_heldout: float | None
    psnr_at: dict = field(default_factory=dict)
    log: list = field(default_factory=list)
    heldout_renders: list = field(default_factory=list)
    """The final field's renders (H, W, 3) of the held-out views (empty without them)."""
    compile_time_s: float = 0.0
    """Compiling (or loading) the step's and the occupancy update's programs before the
    run [s]; not on the training clock (``wall_time_s``)."""


def render_options(bounds, config: TrainConfig, chunk: int | None = None) -> RenderConfig:
    """The sampling used for training (``chunk`` rays per call; default rays_per_step)."""
    rays = chunk or config.rays_per_step
    opts = RenderConfig.for_bounds(bounds, config.samples_across)
    return dataclasses.replace(opts, budget=max(rays * config.samples_per_ray, opts.num_samples))


def carve(data: Dataset, occupancy: OccupancyGrid, background: str, margin_px: int = 2) -> np.ndarray:
    """Cells of ``occupancy`` that can hold the object: (n, n, n) bool, False where a cell's
    centre projects onto background in some view (the visual hull).

    Background: alpha < 0.01 with masks; else every channel >= 0.99 (white) or <= 0.01 (black).
    The background is shrunk by ``margin_px`` pixels first, so cells across the silhouette stay.
    """
    from scipy import ndimage

    if data.alpha is not None:
        back = data.alpha < 0.01
    elif background == "white":
        back = np.all(data.images >= 0.99, axis=-1)
    elif background == "black":
        back = np.all(data.images <= 0.01, axis=-1)
    else:
        return np.ones(occupancy.density.shape, bool)
    structure = np.ones((1, 2 * margin_px + 1, 2 * margin_px + 1), bool)
    back = ndimage.binary_erosion(back, structure=structure, border_value=1)
    centres = np.asarray(occupancy.cell_centres(), np.float64)
    keep = np.ones(len(centres), bool)
    pose = np.asarray(data.cameras.camera_to_world, np.float64)
    focal = np.asarray(data.cameras.focal, np.float64)
    principal = np.asarray(data.cameras.principal, np.float64)
    h, w = data.cameras.height, data.cameras.width
    sign = np.array([1.0, -1.0, -1.0]) if data.cameras.convention == "blender" else np.ones(3)
    for k in range(data.num_images):
        p = (centres - pose[k, :3, 3]) @ pose[k, :3, :3] * sign  # OpenCV camera frame: +z ahead, +y down
        ahead = p[:, 2] > 1e-9
        z = np.where(ahead, p[:, 2], 1.0)
        u = np.floor(focal[k, 0] * p[:, 0] / z + principal[k, 0]).astype(np.int64)
        v = np.floor(focal[k, 1] * p[:, 1] / z + principal[k, 1]).astype(np.int64)
        seen = ahead & (u >= 0) & (u < w) & (v >= 0) & (v < h)
        keep[seen] &= ~back[k][v[seen], u[seen]]
    return keep.reshape(occupancy.density.shape)


def _background(config: TrainConfig, key, n):
    if config.background == "random":
        return jax.random.uniform(key, (n, 3), jnp.float32)
    return jnp.full((n, 3), 1.0 if config.background == "white" else 0.0, jnp.float32)


def _make_step(config: TrainConfig, options: RenderConfig, optimizer, height: int, width: int):
    n = config.rays_per_step

    def step(field, opt_state, occupancy, images, alpha, cameras, key, lr):
        k_ray, k_jit, k_bg = jax.random.split(key, 3)
        idx = jax.random.randint(k_ray, (n,), 0, images.shape[0] * height * width)
        cam = idx // (height * width)
        pix = idx % (height * width)
        v, u = pix // width, pix % width
        origins, dirs = pixel_rays(cameras, cam, u.astype(jnp.float32) + 0.5, v.astype(jnp.float32) + 0.5)
        rgb = images.reshape(-1, 3)[idx]
        bg = _background(config, k_bg, n)
        if alpha is not None:
            a = alpha.reshape(-1)[idx]
            target = rgb * a[:, None] + bg * (1.0 - a[:, None])
        else:
            target = rgb

        def loss_fn(params):
            out = render_rays(dataclasses.replace(field, params=params), origins, dirs, options, occupancy=occupancy,
                              background=bg, key=k_jit)
            w = out.complete.astype(jnp.float32)
            count = jnp.maximum(w.sum(), 1.0)
            mse = jnp.sum(w * jnp.mean((out.rgb - target) ** 2, axis=-1)) / count
            loss = mse
            if alpha is not None and config.mask_weight > 0:
                loss = loss + config.mask_weight * jnp.sum(w * (out.alpha - a) ** 2) / count
            fitted = jnp.sum(jnp.where(out.complete, out.samples, 0))
            return loss, (mse, w.sum(), fitted / jnp.maximum(w.sum(), 1.0))

        (loss, (mse, complete, samples)), grads = jax.value_and_grad(loss_fn, has_aux=True)(field.params)
        opt_state.hyperparams["learning_rate"] = lr
        updates, opt_state = optimizer.update(grads, opt_state, field.params)
        params = optax.apply_updates(field.params, updates)
        return dataclasses.replace(field, params=params), opt_state, loss, mse, complete, samples

    return jax.jit(step)


def evaluate(field: HashGridField, occupancy: OccupancyGrid, data: Dataset, config: TrainConfig,
             chunk: int = 4096) -> tuple[float, list[np.ndarray]]:
    """Mean held-out PSNR [dB] over ``data``'s views (images composited on the configured
    background, white for ``random``) and the rendered images (H, W, 3)."""
    options = render_options(field.bounds(), config, chunk)
    bg = 0.0 if config.background == "black" else 1.0
    scores, renders = [], []
    for i in range(data.num_images):
        out = render_image(field, data.cameras, i, options, occupancy=occupancy, background=bg, chunk=chunk)
        ref = data.images[i]
        if data.alpha is not None:
            ref = ref * data.alpha[i][..., None] + bg * (1.0 - data.alpha[i][..., None])
        scores.append(psnr(np.clip(out.rgb, 0.0, 1.0), ref))
        renders.append(out.rgb)
    return float(np.mean(scores)), renders


def train(data: Dataset, config: TrainConfig, *, heldout: Dataset | None = None, out_dir: str | Path | None = None,
          resume: bool = False, progress: Callable[[dict], None] | None = None) -> TrainResult:
    """Train a field on ``data`` (already split: pass the held-out views as ``heldout``).

    out_dir: field directory for checkpoints (every ``checkpoint_minutes`` and at the end);
    resume: continue from the checkpoint in ``out_dir`` (parameters, Adam state, occupancy
    grid, step and clock); progress: called after every step with a dict (step, elapsed_s,
    loss, psnr_train, lr, complete: the fraction of the step's rays trained, samples_per_ray
    of those, fraction: of the run done). The training clock (``config.minutes``, the
    learning-rate schedule, ``wall_time_s``) starts after the step's program is compiled
    (``compile_time_s``), so a run's schedule, and with a step budget its result, do not
    depend on the compilation cache. ``rays_per_s`` counts trained (complete) rays over
    that clock.

    Raises DanoError for an inconsistent configuration, FileFormatError for a bad checkpoint.
    """
    config.check_data(data)
    bounds = data.bounds
    options = render_options(bounds, config)
    threshold = -math.log1p(-config.occupancy_alpha) / options.step
    optimizer = optax.inject_hyperparams(optax.adam)(learning_rate=config.learning_rate, b1=0.9, b2=0.99, eps=1e-15)
    field = HashGridField.create(bounds, config.field, seed=config.seed)
    occupancy = OccupancyGrid.create(bounds, config.occupancy_resolution, threshold)
    opt_state = optimizer.init(field.params)
    start_step, clock0, log = 0, 0.0, []
    if resume:
        fresh = field  # its config has the unit of σ resolved from the box, as the checkpoint's
        field, occupancy, meta = load_field(out_dir)
        opt_state = load_optimizer_state(out_dir, opt_state)
        if field.config != fresh.config or not np.allclose(field.bounds(), bounds, atol=1e-6):
            raise DanoError(f"{out_dir}: the checkpoint's field architecture or box differs from this run's")
        start_step = int(meta["training"].get("step", 0))
        clock0 = float(meta["training"].get("elapsed_s", 0.0))
    cameras = data.cameras
    images = jnp.asarray(data.images, jnp.float32)
    alpha = None if data.alpha is None else jnp.asarray(data.alpha, jnp.float32)
    step_fn = _make_step(config, options, optimizer, cameras.height, cameras.width)
    keep = jnp.asarray(carve(data, occupancy, config.background)) if config.carve else None
    occ_fn = jax.jit(lambda f, g, k: update_occupancy(g, f.density, k, keep=keep))
    key = jax.random.fold_in(jax.random.PRNGKey(config.seed), start_step)
    budget_s = config.minutes * 60.0
    # compiled before the clock starts: the schedule follows the training clock, so a first
    # step that waited for its compilation skewed it (the same seed trained to 40.21 dB with
    # an empty compilation cache and 40.20 with a warm one; 40.67 and 40.20 on jax 0.12)
    t_compile = time.perf_counter()
    lr0 = jnp.float32(config.learning_rate)
    step_fn = step_fn.lower(field, opt_state, occupancy, images, alpha, cameras, key, lr0).compile()
    occ_fn = occ_fn.lower(field, occupancy, key).compile()
    compile_time_s = time.perf_counter() - t_compile
    psnr_at: dict = {}
    pending = sorted(m for m in config.eval_at_minutes if m * 60.0 > clock0)
    elapsed = clock0
    tic = time.perf_counter() - clock0
    paused = 0.0
    last_checkpoint = clock0
    step = start_step
    trained_rays = 0

    def info(extra=None):
        return {"step": step, "elapsed_s": elapsed, "rays_per_step": config.rays_per_step, "data": data.source,
                "sample_step": options.step,
                "psnr_at_minutes": psnr_at, **(extra or {})}

    while True:
        fraction = min(1.0, max(elapsed / budget_s, step / config.steps if config.steps else 0.0))
        if fraction >= 1.0:
            break
        lr = config.learning_rate * (config.final_learning_rate / config.learning_rate) ** fraction
        key, k_step, k_occ = jax.random.split(key, 3)
        if step % config.occupancy_every == 0:
            occupancy = occ_fn(field, occupancy, k_occ)
        field, opt_state, loss, mse, complete, samples = step_fn(field, opt_state, occupancy, images, alpha, cameras,
                                                                 k_step, jnp.float32(lr))
        loss = float(loss)
        if not math.isfinite(loss):
            raise DanoError(f"training diverged at step {step} (loss {loss}); try a smaller --learning-rate")
        step += 1
        elapsed = time.perf_counter() - tic - paused
        trained_rays += int(complete)
        record = {"step": step, "elapsed_s": elapsed, "loss": loss, "psnr_train": -10.0 * math.log10(max(float(mse),
                  1e-12)), "lr": lr, "complete": float(complete) / config.rays_per_step,
                  "samples_per_ray": float(samples)}
        log.append(record)
        while pending and elapsed >= pending[0] * 60.0 and heldout is not None:
            t0 = time.perf_counter()
            psnr_at[f"{pending.pop(0):g}"] = evaluate(field, occupancy, heldout, config)[0]
            paused += time.perf_counter() - t0
        if out_dir is not None and elapsed - last_checkpoint >= config.checkpoint_minutes * 60.0:
            t0 = time.perf_counter()
            save_field(out_dir, field, occupancy, info(), opt_state)
            paused += time.perf_counter() - t0
            last_checkpoint = elapsed
        if progress is not None:
            progress({**record, "fraction": fraction})
    occupancy = occ_fn(field, occupancy, key)
    score, renders = evaluate(field, occupancy, heldout, config) if heldout is not None else (None, [])
    wall = elapsed - clock0
    result = TrainResult(field, occupancy, step, elapsed, trained_rays / max(wall, 1e-9), score, psnr_at, log,
                         renders, compile_time_s)
    if out_dir is not None:
        save_field(out_dir, field, occupancy, info({"psnr_heldout": score}), opt_state)
    return result


def write_outputs(out_dir: str | Path, result: TrainResult, config: TrainConfig, dataset: Dataset, train_set: Dataset,
                  heldout: Dataset, data: str | Path) -> dict:
    """Beside the field directory ``out_dir`` that :func:`train` wrote: ``report.json`` (the
    returned report: ``psnr_heldout`` [dB], ``wall_time_s`` (the training clock),
    ``compile_time_s`` (before it), ``rays_per_s``, ``steps``,
    ``psnr_at_minutes``, view counts, ``image_size``, ``occupied_fraction``, ``data``,
    ``field``), ``config.json`` (the resolved configuration), ``log.csv`` (the training log)
    and ``heldout.png`` (renders over images). Each file is written atomically."""
    out_dir = Path(out_dir)
    report = {
        "psnr_heldout": result.psnr_heldout, "wall_time_s": result.wall_time_s,
        "compile_time_s": result.compile_time_s, "rays_per_s": result.rays_per_s,
        "steps": result.steps, "psnr_at_minutes": result.psnr_at, "train_views": train_set.num_images,
        "heldout_views": heldout.num_images, "image_size": [dataset.cameras.width, dataset.cameras.height],
        "occupied_fraction": result.occupancy.fraction_occupied(), "data": str(data), "field": str(out_dir),
    }
    resolved = dataclasses.asdict(config) | {"data": str(data), "bounds": dataset.bounds.tolist()}
    atomic_write(out_dir / "config.json", lambda f: f.write(config_json(resolved).encode()))
    atomic_write(out_dir / "report.json", lambda f: f.write((json.dumps(report, indent=2) + "\n").encode()))
    buffer = io.StringIO()
    writer = csv.DictWriter(buffer, fieldnames=["step", "elapsed_s", "loss", "psnr_train", "lr", "complete",
                                                "samples_per_ray"])
    writer.writeheader()
    writer.writerows(result.log)
    atomic_write(out_dir / "log.csv", lambda f: f.write(buffer.getvalue().encode()))
    references, titles = [], []
    for k, image in enumerate(result.heldout_renders[:4]):
        ref = heldout.images[k]
        if heldout.alpha is not None:
            ref = ref * heldout.alpha[k][..., None] + (1.0 - heldout.alpha[k][..., None])
        references.append(ref)
        titles.append(f"{heldout.names[k]}\n{psnr(np.clip(image, 0.0, 1.0), ref):.2f} dB")
    plot_heldout(result.heldout_renders, references, titles, out_dir / "heldout.png")
    return report


@dataclass(frozen=True)
class TrainFieldConfig:
    """Train a density (radiance) field from posed images; `dano build DIR` makes it a DANO."""

    data: Annotated[Path, tyro.conf.Positional, tyro.conf.arg(metavar="DATA")]
    """a transforms.json (Blender/nerfstudio; or its folder) or an .npz image set (images, poses, focal)."""
    out: Annotated[Path, tyro.conf.arg(aliases=("-o",))]
    """the field directory to write (field.json, field.npz, optimizer.npz, config.json, report.json, log.csv,
    heldout.png). Checkpoints are written every 2 minutes of training; an interrupted run keeps its last
    checkpoint (continue it with --resume)."""
    minutes: float = 3.0
    """training time [min] (compiling before it and evaluation excluded)."""
    steps: int = 0
    """also stop after this many steps (0: only the clock stops)."""
    holdout: int = 10
    """views held out for the PSNR (evenly spread over the set)."""
    bounds: tuple[float, float, float, float, float, float] | None = None
    """the object box XLO YLO ZLO XHI YHI ZHI [data units] (default: the data's, else +-1.5)."""
    background: str = "white"
    """white, black or random (random needs RGBA images)."""
    mask_weight: float = 0.0
    """weight of an alpha (mask) loss; needs RGBA images."""
    rays_per_step: int = 4096
    """rays per Adam step."""
    eval_at: tuple[float, ...] = ()
    """also measure held-out PSNR when training passes these minutes (e.g. 1 3)."""
    seed: int = 0
    """random seed."""
    resume: bool = False
    """continue the run checkpointed in OUT."""
    json_: Annotated[bool, tyro.conf.arg(name="json")] = False
    """print one JSON object (psnr_heldout, wall_time_s, rays_per_s, steps, psnr_at_minutes, ...)."""
    quiet: bool = False
    """no progress bar."""

    def __post_init__(self):
        out = Path(self.out)
        if out.exists() and not self.resume and (not out.is_dir() or any(out.iterdir())):
            hint = " (a field directory: --resume continues it)" if (out / "field.json").exists() else ""
            raise DanoError(f"{out}: exists and is not empty{hint}; choose a new output folder")
        if self.resume and not (out / "field.json").exists():
            raise DanoError(f"{out}: --resume needs a field directory written by `dano train-field`")
        late = [m for m in self.eval_at if m > self.minutes]
        if late:  # (the run would end before them: psnr_at_minutes would leave them out without a word)
            raise DanoError(f"--eval-at {' '.join(f'{m:g}' for m in late)}: after the end of the run "
                            f"(--minutes {self.minutes:g})")


def train_field(config: TrainFieldConfig, progress: Callable[[dict], None] | None = None) -> tuple[dict, TrainResult]:
    """``dano train-field``: read the images (:func:`~dano.nerf.load_dataset`), hold out
    ``holdout`` views, train (:func:`train`, checkpointing into ``out``) and write the report,
    configuration, log and held-out figure (:func:`write_outputs`). Returns (report, result).
    Raises DanoError for bad options or data."""
    box = None if config.bounds is None else np.asarray(config.bounds, dtype=np.float64).reshape(2, 3)
    dataset = load_dataset(config.data, bounds=box)
    train_config = TrainConfig(minutes=config.minutes, steps=config.steps, holdout=config.holdout,
                               background=config.background, mask_weight=config.mask_weight,
                               rays_per_step=config.rays_per_step, eval_at_minutes=tuple(config.eval_at),
                               seed=config.seed).check_data(dataset)
    train_set, held = dataset.split(config.holdout)
    result = train(train_set, train_config, heldout=held, out_dir=config.out, resume=config.resume, progress=progress)
    return write_outputs(config.out, result, train_config, dataset, train_set, held, config.data), result
