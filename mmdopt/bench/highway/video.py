"""Videos that show the planner: highway-env's frames with the executed plan, the predicted
futures (the reduced set highlighted) and labels drawn on them.

* :func:`headless_display` — SDL settings for rendering without a screen, set before highway-env
  opens its viewer: the ``offscreen`` video driver (highway-env's viewer turns itself off under
  the ``dummy`` driver, which would give blank frames) and a private ``XDG_RUNTIME_DIR`` (a
  temporary folder of mode 0700), which silences SDL's "XDG_RUNTIME_DIR is invalid or not set".
* :class:`PlanRecorder` — the ``callback`` of :func:`mmdopt.receding.run_receding`: keeps, for
  each replan, the plan's Cartesian trajectory, the obstacle samples it was planned against, the
  indices of the reduced set (``Plan.reduced_set.indices``), its status and the time.
* :func:`overlay` — draws one step's record on one frame, using the frame's view (the world
  position of its top-left pixel and the pixels per metre, highway-env's ``WorldSurface``
  transform ``pos2pix``).
* :func:`encode` — MP4 when imageio's ffmpeg plugin is installed and asked for, else a GIF.
"""

from __future__ import annotations

import os
import tempfile
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

PLAN_COLOUR = (30, 200, 30)
SAMPLE_COLOUR = (120, 150, 235)
REDUCED_COLOUR = (255, 120, 0)
#: the samples of each route (mode) of a car at a junction, by route index
MODE_COLOURS = ((70, 110, 255), (230, 50, 190), (0, 190, 200), (250, 170, 0), (150, 80, 255),
                (120, 120, 120))  # fmt: skip
#: the ego's route ahead at a junction
ROUTE_COLOUR = (250, 250, 250)
LABEL_BACKGROUND = (0, 0, 0)
LABEL_COLOUR = (255, 255, 255)


def headless_display() -> None:
    """Let highway-env render without a screen and without SDL's ``XDG_RUNTIME_DIR`` message:
    the ``offscreen`` SDL video driver unless another non-``dummy`` one is set, and a private
    ``XDG_RUNTIME_DIR`` unless a usable one is set.  Call before highway-env's first render."""
    if os.environ.get("SDL_VIDEODRIVER", "dummy") == "dummy":
        os.environ["SDL_VIDEODRIVER"] = "offscreen"
    xdg = os.environ.get("XDG_RUNTIME_DIR", "")
    if not (xdg and os.path.isdir(xdg) and os.access(xdg, os.W_OK)):
        os.environ["XDG_RUNTIME_DIR"] = tempfile.mkdtemp(prefix="mmdopt-sdl-")  # mode 0700


@dataclass
class StepDrawing:
    """What is drawn during one replan period: ``time`` (s), ``plan_xy`` (K, 2), ``samples``
    (O, n, K, 2) obstacle samples, ``reduced`` (O, m) indices into the n samples (``None``: no
    reduced set, every sample drawn alike) and the plan's ``status``; at a junction ``modes``
    (O, n), the route (mode) of each sample (the route predictor's), and ``route_xy`` (R, 2), the
    ego's route ahead."""

    time: float
    plan_xy: np.ndarray
    samples: np.ndarray
    reduced: np.ndarray | None
    status: str
    modes: np.ndarray | None = None
    route_xy: np.ndarray | None = None


@dataclass
class PlanRecorder:
    """``callback(i, observation, plan, outcome)`` of :func:`mmdopt.receding.run_receding` that
    keeps a :class:`StepDrawing` per replan in ``steps``."""

    steps: list[StepDrawing] = field(default_factory=list)

    def __call__(self, i, obs, plan, outcome) -> None:
        samples = np.asarray(obs.obstacles, dtype=float)
        reduced = None
        rs = getattr(plan, "reduced_set", None)
        if rs is not None and samples.shape[0] > 0:
            # the planner pads the obstacles with phantoms after the real ones (receding loop)
            reduced = np.asarray(rs.indices)[: samples.shape[0]]
        info = obs.info or {}
        modes = info.get("modes")
        if modes is not None and np.shape(modes) != samples.shape[:2]:
            modes = None  # not the futures drawn for this plan
        self.steps.append(
            StepDrawing(
                time=float(obs.time),
                plan_xy=np.column_stack([np.asarray(plan.x), np.asarray(plan.y)]),
                samples=samples,
                reduced=reduced,
                status=str(plan.status_text),
                modes=None if modes is None else np.asarray(modes),
                route_xy=info.get("route_xy"),
            )
        )


def _pix(xy, view) -> list[tuple[float, float]]:
    """World points (..., 2) → pixel coordinates with a frame's view ``(origin, scaling)``
    (highway-env's ``WorldSurface.pos2pix``)."""
    origin, scaling = view
    p = (np.asarray(xy, dtype=float).reshape(-1, 2) - np.asarray(origin)) * float(scaling)
    return [(float(a), float(b)) for a, b in p]


def overlay(
    frame: np.ndarray,
    view: tuple[np.ndarray, float],
    step: StepDrawing | None,
    labels: list[str],
) -> np.ndarray:
    """``frame`` (H, W, 3) with ``step``'s plan (wide, green), its obstacle samples (thin blue
    lines; the reduced set's thicker, in orange) and the ``labels`` (top left) drawn on it.  At a
    junction (``step.modes``) each sample is coloured by its route (:data:`MODE_COLOURS`), the
    reduced set's thicker in the same colour, and the ego's route (``step.route_xy``) is drawn
    under the plan."""
    from PIL import Image, ImageDraw

    img = Image.fromarray(np.ascontiguousarray(frame, dtype=np.uint8))
    draw = ImageDraw.Draw(img)
    if step is not None:
        # the plan first and wide, so the samples of a car in the ego's lane show on top of it
        if step.route_xy is not None:
            draw.line(_pix(step.route_xy, view), fill=ROUTE_COLOUR, width=2)
        draw.line(_pix(step.plan_xy, view), fill=PLAN_COLOUR, width=5)
        O = step.samples.shape[0]
        for o in range(O):
            chosen = set() if step.reduced is None else {int(j) for j in step.reduced[o]}

            def colour(j, reduced, o=o):
                if step.modes is None:
                    return REDUCED_COLOUR if reduced else SAMPLE_COLOUR
                return MODE_COLOURS[int(step.modes[o, j]) % len(MODE_COLOURS)]

            for j in range(step.samples.shape[1]):
                if j not in chosen:
                    draw.line(_pix(step.samples[o, j], view), fill=colour(j, False), width=1)
            for j in sorted(chosen):
                draw.line(_pix(step.samples[o, j], view), fill=colour(j, True), width=3)
    y = 4
    for text in labels:
        box = draw.textbbox((6, y), text)
        draw.rectangle((box[0] - 2, box[1] - 2, box[2] + 2, box[3] + 2), fill=LABEL_BACKGROUND)
        draw.text((6, y), text, fill=LABEL_COLOUR)
        y = box[3] + 6
    return np.asarray(img)


def overlay_episode(
    frames,
    views,
    steps: list[StepDrawing],
    *,
    method: str,
    speeds,
    frame_dt: float,
    frames_per_step: int,
) -> list[np.ndarray]:
    """Every frame of an episode with its replan period's drawing and the labels method, time,
    speed and status.  Frame 0 is the initial scene and frame ``k ≥ 1`` the ``k``-th simulator
    step, executed during replan ``(k − 1) // frames_per_step``."""
    if len(frames) != len(views):
        raise ValueError(f"frames ({len(frames)}) and views ({len(views)}) differ in number")
    out = []
    for k, (frame, view) in enumerate(zip(frames, views, strict=True)):
        i = max(k - 1, 0) // frames_per_step
        step = steps[i] if i < len(steps) else None
        speed = float(speeds[k]) if k < len(speeds) else float("nan")
        labels = [f"{method}   t = {k * frame_dt:5.1f} s   speed = {speed:5.1f} m/s"]
        if step is not None:
            labels.append(f"plan: {step.status}"[:70])
        out.append(overlay(frame, view, step, labels))
    return out


def encode(path: str | Path, frames, fps: float) -> Path:
    """Write ``frames`` to ``path``: MP4 when ``path`` ends in ``.mp4`` and imageio's ffmpeg
    plugin (``imageio-ffmpeg``) is installed, otherwise a GIF (suffix replaced); returns the
    path written."""
    import imageio.v2 as imageio

    if not frames:
        raise ValueError("frames is empty: nothing to write")
    path = Path(path)
    if path.suffix == ".mp4":
        try:
            import imageio_ffmpeg  # noqa: F401

            imageio.mimsave(path, frames, fps=fps)
            return path
        except ImportError:
            pass
    path = path.with_suffix(".gif")
    imageio.mimsave(path, frames, duration=1000.0 / fps, loop=0)
    return path
