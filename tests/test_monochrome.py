"""A monochrome target stays monochrome (:mod:`facetransfer.monochrome`).

Before: a transfer onto black-and-white footage pasted the colour source's mouth into it, and
the target's lip colour (grey) over the source's (red) made the lips cyan.
"""

from __future__ import annotations

import sys
from pathlib import Path

import cv2
import numpy as np

sys.path.insert(0, str(Path(__file__).parent))

from facetransfer import lip_colour as lc  # noqa: E402
from facetransfer import rewrite_clip as rc  # noqa: E402
from facetransfer.monochrome import MONO_LEVELS, is_monochrome, monochrome_changes  # noqa: E402
from facetransfer.rewrite_options import RewriteOptions  # noqa: E402

from test_lip_colour import clips, weights  # noqa: E402,F401  (fixtures)


def _grey(frames: np.ndarray) -> np.ndarray:
    return np.stack([np.repeat(cv2.cvtColor(f, cv2.COLOR_RGB2GRAY)[..., None], 3, axis=2)
                     for f in frames])


def test_a_clip_is_monochrome_when_its_channels_agree_up_to_decoding_noise():
    rng = np.random.default_rng(0)
    grey = np.repeat(rng.integers(20, 230, (6, 40, 50, 1), np.uint8), 3, axis=3)
    assert is_monochrome(grey)
    noisy = np.clip(grey.astype(int) + rng.integers(-1, 2, grey.shape), 0, 255).astype(np.uint8)
    assert is_monochrome(noisy)                                   # within MONO_LEVELS
    tinted = grey.copy()
    tinted[3, :, :, 0] = np.clip(tinted[3, :, :, 0].astype(int) + MONO_LEVELS + 3, 0, 255)
    assert not is_monochrome(tinted)                              # one sampled frame in colour
    assert not is_monochrome(grey[:0])


def test_the_changed_pixels_turn_grey_and_the_rest_stays_to_the_bit():
    rng = np.random.default_rng(1)
    frame = np.repeat(rng.integers(0, 256, (30, 40, 1), np.uint8), 3, axis=2)
    image = frame.copy()
    image[10:20, 5:25] = (200, 40, 60)                            # a red patch pasted in
    out = monochrome_changes(image, frame)
    np.testing.assert_array_equal(out[:10], frame[:10])
    np.testing.assert_array_equal(out[20:], frame[20:])
    want = cv2.cvtColor(np.full((1, 1, 3), (200, 40, 60), np.uint8), cv2.COLOR_RGB2GRAY)[0, 0]
    np.testing.assert_array_equal(out[10:20, 5:25], want)         # BT.601 luma: 90
    assert want == 90
    assert monochrome_changes(frame, frame) is frame


def test_the_grey_tint_is_one_factor_the_ratio_of_lumas():
    t = lc.LipTint.of(np.ones(4), [0.8, 0.8, 0.8], [1.2, 0.5, 0.6]).grey()
    luma = 0.299 * 1.2 + 0.587 * 0.5 + 0.114 * 0.6
    np.testing.assert_allclose(t.tint, np.full(3, 0.8 / luma))
    assert not np.allclose(lc.LipTint.of(np.ones(4), [0.8] * 3, [1.2, 0.5, 0.6]).tint, t.tint)


def test_a_grey_target_gets_a_grey_face_with_its_own_lip_tone(quick_model, clips, weights):
    """The colour source's mouth on the grey target: every output pixel grey, the pixels the
    rewrite leaves equal to the target's; the lips as light as the target's (the luma tint).
    Measured on the mouth's pixels against the grey target: 2.2 levels (without a tint 12.8;
    before, in colour with the per-channel tint, 19.0 and channels up to 79 levels apart)."""
    target, source, track = clips
    grey = _grey(target)
    topo = weights[0]
    outs = list(rc.rewrite_frames(grey, track, track, quick_model,
                                  mouth_source=rc.MouthSource(source, track), topo=topo,
                                  options=RewriteOptions(lips="model", eyes="target",
                                                         jaw="frame", mouth="frame",
                                                         blend="none")))
    r = rc._ClipRenderer.build(grey, track, track, quick_model,
                               RewriteOptions(lips="model", eyes="target", jaw="frame"),
                               mouth_source=rc.MouthSource(source, track), topo=topo)
    assert r.mono and np.ptp(r.lip_tint.tint) == 0
    for o, g in zip(outs, grey):
        img = o.image.astype(int)
        assert (img[..., 0] == img[..., 1]).all() and (img[..., 1] == img[..., 2]).all()
        same = (o.image == g).all(axis=2)
        assert same.mean() > 0.5 and o.mouth_mask.any()
    # the lips' tone: against the grey target on the mouth's pixels
    err = np.mean([np.abs(o.image[o.mouth_mask].astype(float) - g[o.mouth_mask]).mean()
                   for o, g in zip(outs, grey)])
    assert err < 6.0, err
