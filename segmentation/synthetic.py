"""Seeded synthetic colour scenes with known masks, for tests and benchmarks.

A textured background (smooth colour field, tiles, stripes and blobs), a person-like shape
made of ellipses and polygons in clothing / skin colours, a cast shadow beside the person (the
background's B, G, R scaled by a factor in 0.5-0.7), and Gaussian sensor noise.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

__all__ = ["SyntheticScene", "synthetic_scene"]


@dataclass(frozen=True)
class SyntheticScene:
    """A seeded synthetic scene with its known answers.

    Attributes
    ----------
    background_frames : ndarray, shape (n_bg, h, w, 3), uint8
        Empty-scene frames (noise only).
    frames : ndarray, shape (n, h, w, 3), uint8
        Frames with the person and the shadow.
    person_masks : ndarray of bool, shape (n, h, w)
        True silhouettes.
    shadow_masks : ndarray of bool, shape (n, h, w)
        Shadow pixels not covered by the person.
    clean_background : ndarray, shape (h, w, 3), float32
        Noise-free background.
    """

    background_frames: np.ndarray
    frames: np.ndarray
    person_masks: np.ndarray
    shadow_masks: np.ndarray
    clean_background: np.ndarray


def _background(rng: np.random.Generator, w: int, h: int) -> np.ndarray:
    low = rng.uniform(40, 220, (4, 5, 3)).astype(np.float32)
    bg = cv2.resize(low, (w, h), interpolation=cv2.INTER_CUBIC)
    yy, xx = np.mgrid[0:h, 0:w]
    floor = yy > 0.55 * h  # a coloured floor with tiles, walls with stripes
    tile = (((xx // 40) + (yy // 40)) % 2).astype(np.float32)
    bg[floor] = np.array([60, 140, 70], np.float32) + 25 * tile[floor, None]
    stripes = (np.sin(xx / 6.0) > 0.6) & ~floor
    bg[stripes] *= 0.8
    for _ in range(25):  # furniture-like blobs with sharp edges
        c = tuple(int(v) for v in rng.uniform(20, 235, 3))
        x, y = int(rng.integers(0, w)), int(rng.integers(0, h))
        cv2.rectangle(bg, (x, y), (x + int(rng.integers(10, 60)), y + int(rng.integers(10, 60))), c, -1)
    return np.clip(bg, 0, 255)


def _person(w: int, h: int, cx: float, colours) -> np.ndarray:
    """Label image (h, w) uint8: 0 none, 1..4 clothing/skin parts, for a person centred at ``cx``."""
    lab = np.zeros((h, w), np.uint8)
    s = h / 480.0
    top = int(0.2 * h)

    def pt(dx, dy):
        return int(round(cx + dx * s)), int(round(top + dy * s))

    cv2.ellipse(lab, pt(0, 20), (int(18 * s), int(24 * s)), 0, 0, 360, 1, -1)  # head (skin)
    cv2.ellipse(lab, pt(0, 100), (int(42 * s), int(62 * s)), 0, 0, 360, 2, -1)  # torso (shirt)
    for side in (-1, 1):
        arm = np.array([pt(side * 38, 55), pt(side * 62, 120), pt(side * 70, 175), pt(side * 56, 178),
                        pt(side * 46, 125), pt(side * 26, 80)], np.int32)
        cv2.fillPoly(lab, [arm], 2)
        cv2.circle(lab, pt(side * 63, 184), int(9 * s), 1, -1)  # hands (skin)
        leg = np.array([pt(side * 6, 150), pt(side * 38, 150), pt(side * 40 + 4 * side, 300),
                        pt(side * 16, 300)], np.int32)
        cv2.fillPoly(lab, [leg], 3)  # trousers
        cv2.ellipse(lab, pt(side * 28 + 6 * side, 306), (int(20 * s), int(8 * s)), 0, 0, 360, 4, -1)  # shoes
    return lab


def _shadow_like_fraction(colour, bg: np.ndarray) -> float:
    """Fraction of background pixels of which ``colour`` (B, G, R) looks like a shadow / highlight:
    ``colour ~ s * bg`` with ``s`` in [0.4, 1.1] within 30 levels (colour alone cannot tell them apart)."""
    c = np.asarray(colour, np.float32)
    b = bg.reshape(-1, 3)
    s = (b @ c) / np.maximum(np.einsum("ij,ij->i", b, b), 1e-6)
    resid = np.linalg.norm(c[None, :] - s[:, None] * b, axis=1)
    return float(np.mean((s >= 0.4) & (s <= 1.1) & (resid < 30.0)))


def _clothing_colour(rng, bg: np.ndarray, low: float, high: float, avoid: bool):
    colour = tuple(rng.uniform(low, high, 3))
    for _ in range(100):  # redraw colours that are a shadow of much of the background
        if not avoid or _shadow_like_fraction(colour, bg[::8, ::8]) < 0.02:
            break
        colour = tuple(rng.uniform(low, high, 3))
    return colour


def synthetic_scene(rng: np.random.Generator, *, size: tuple[int, int] = (640, 480), n_background: int = 50,
                    n_frames: int = 8, noise_sigma: float = 3.0, avoid_shadow_like: bool = True) -> SyntheticScene:
    """A seeded scene; the person walks left to right over ``n_frames``.

    Parameters
    ----------
    rng : numpy.random.Generator
    size : (int, int)
        (w, h), pixels.
    n_background : int
        Empty-scene frames.
    n_frames : int
        Frames with the person.
    noise_sigma : float
        Gaussian sensor noise, grey levels.
    avoid_shadow_like : bool
        Redraw clothing colours that equal a copy at 0.4-1.1 times the brightness of more than a
        fiftieth of the background (there colour alone cannot separate a person from a shadow);
        False keeps any random colour (the benchmark measures how often such scenes fail).

    Returns
    -------
    SyntheticScene
    """
    w, h = size
    bg = _background(rng, w, h)
    colours = {1: (120, 150, 205), 2: _clothing_colour(rng, bg, 20, 230, avoid_shadow_like),
               3: _clothing_colour(rng, bg, 20, 120, avoid_shadow_like), 4: (30, 30, 35)}
    noise = lambda img: np.clip(img + rng.normal(0, noise_sigma, img.shape), 0, 255).astype(np.uint8)  # noqa: E731
    bgs = np.stack([noise(bg) for _ in range(n_background)])
    frames, persons, shadows = [], [], []
    for k in range(n_frames):
        cx = w * (0.25 + 0.5 * k / max(n_frames - 1, 1))
        lab = _person(w, h, cx, colours)
        person = lab > 0
        foot_y = int(0.2 * h + 306 * h / 480.0)
        sh = np.zeros((h, w), np.uint8)
        poly = np.array([(cx - 30 * h / 480, foot_y + 4), (cx + 40 * h / 480, foot_y + 8),
                         (cx + 190 * h / 480, foot_y + 70 * h / 480), (cx + 120 * h / 480, foot_y + 85 * h / 480)],
                        np.int32)
        cv2.fillPoly(sh, [poly], 1)
        shadow = (sh > 0) & ~person
        img = bg.copy()
        img[shadow] *= rng.uniform(0.5, 0.7)
        for label, colour in colours.items():
            tex = 1.0 + 0.08 * np.sin(np.arange(w) / 3.0)[None, :]  # cloth texture
            m = lab == label
            img[m] = (np.array(colour, np.float32)[None, :] * np.broadcast_to(tex, (h, w))[m][:, None])
        frames.append(noise(img))
        persons.append(person)
        shadows.append(shadow)
    return SyntheticScene(bgs, np.stack(frames), np.stack(persons), np.stack(shadows), bg.astype(np.float32))
