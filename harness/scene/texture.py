"""A cloth-like texture for the rendered humanoid, so that corners exist on the body as on clothing.

The pattern is a plaid: warp stripes (along the texture's columns) and weft stripes (along its rows) of random
widths and muted colours from a seeded generator; where they cross the two colours mix, as the threads of a
tartan do seen from a few metres, and each stripe's brightness is jittered a little, like dyed yarn. Where
stripes of different colours cross there are corners in every direction, which Shi-Tomasi finds and
Lucas-Kanade follows without the aperture problem of plain stripes. Nothing is finer than a stripe: detail
below about 1.5 px in the image (1 cm at 4 m with the default camera) would alias, and an aliasing pattern
moves unlike the surface it lies on.

MuJoCo maps a 2D texture onto primitive geoms in the geom's own frame, so the pattern moves with the body
(``benchmarks/video_flows.py`` measures flows against the motion of the surface point under each feature).
With ``texuniform`` the texture repeats ``TEXTURE_REPEAT`` times per metre.
"""

from __future__ import annotations

import mujoco
import numpy as np

TEXTURE_PX = 256          # texture image side: one texture pixel is 1 mm on the body
TEXTURE_REPEAT = 4.0      # repeats per metre: one texture spans 25 cm
STRIPE_PX = (15, 50)      # stripe widths, texture pixels (1.5-5 cm: 2-7 px at 4 m with the default 640x480,
                          # 45 degree camera)
DARK = np.array([         # muted clothing colours, RGB 0-1: navy, bottle green, burgundy, charcoal
    [0.10, 0.13, 0.30],
    [0.08, 0.26, 0.15],
    [0.40, 0.08, 0.12],
    [0.15, 0.15, 0.17],
])
LIGHT = np.array([        # ... and light ones: cream, ochre, sky blue, rose
    [0.88, 0.85, 0.74],
    [0.80, 0.62, 0.22],
    [0.55, 0.68, 0.85],
    [0.85, 0.55, 0.55],
])
YARN_JITTER = 0.1         # relative brightness jitter per stripe
TEXTURE_NAME = "cloth"
MATERIAL_NAME = "cloth"
TEXTURE_SEED = 2026       # the one cloth every textured scene wears


def _stripes(rng: np.random.Generator, size: int) -> np.ndarray:
    """A colour ``(size, 3)`` per texture row (or column): consecutive stripes of random widths, dark and light
    in turn (every stripe edge is a step in brightness, so every crossing of two edges is a corner), each of a
    random colour of its kind with its brightness jittered."""
    out = np.empty((size, 3))
    k, light = 0, bool(rng.integers(2))
    while k < size:
        width = int(rng.integers(STRIPE_PX[0], STRIPE_PX[1] + 1))
        palette = LIGHT if light else DARK
        out[k:k + width] = palette[rng.integers(len(palette))] * (1.0 + YARN_JITTER * rng.standard_normal())
        light, k = not light, k + width
    return out


def cloth_texture(rng: np.random.Generator, size: int = TEXTURE_PX) -> np.ndarray:
    """A plaid ``(size, size, 3) uint8`` RGB: the mean of a row's weft colour and a column's warp colour; the
    same generator state gives the same image."""
    warp, weft = _stripes(rng, size), _stripes(rng, size)
    image = 0.5 * (weft[:, None, :] + warp[None, :, :])
    return np.clip(np.round(255.0 * image), 0, 255).astype(np.uint8)


def dress(spec: mujoco.MjSpec, seed: int = TEXTURE_SEED) -> None:
    """Dress the humanoid of a model being built in cloth: every geom there so far (the body's; obstacles are
    added later and keep their own look) gets a material with the cloth texture (white base colour, so the
    texture's own colours show; uniform repeats per metre). The floor keeps its material."""
    image = cloth_texture(np.random.default_rng(seed))
    tex = spec.add_texture(name=TEXTURE_NAME, type=mujoco.mjtTexture.mjTEXTURE_2D, width=image.shape[1],
                           height=image.shape[0], nchannel=3)
    tex.data = image.tobytes()
    mat = spec.add_material(name=MATERIAL_NAME, rgba=[1.0, 1.0, 1.0, 1.0], texuniform=True,
                            texrepeat=[TEXTURE_REPEAT, TEXTURE_REPEAT], specular=0.1)
    textures = [""] * len(mat.textures)
    textures[mujoco.mjtTextureRole.mjTEXROLE_RGB] = TEXTURE_NAME
    mat.textures = textures
    for geom in spec.geoms:
        if geom.name != "floor":
            geom.material = MATERIAL_NAME
