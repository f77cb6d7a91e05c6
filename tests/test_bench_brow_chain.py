"""The brow chain benchmark's measures (benchmarks/bench_brow_chain.py): what else a result's
reading follows once the plan is regressed out, and the chain's partial correlations."""

import sys
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))

bc = pytest.importorskip("bench_brow_chain")


def _series(rng, n=120):
    from facetransfer.arkit import ARKIT_NAMES

    plan = rng.uniform(0, 1, n)
    blink = rng.uniform(0, 1, n)
    acts = {"plan": rng.uniform(0, 1, (n, len(ARKIT_NAMES))),
            "target": rng.uniform(0, 1, (n, len(ARKIT_NAMES)))}
    acts["plan"][:, ARKIT_NAMES.index("browInnerUp")] = plan
    acts["target"][:, ARKIT_NAMES.index("eyeBlinkLeft")] = blink
    return plan, blink, acts, rng.normal(0, 5, (n, 3))


def test_residual_drivers_names_the_planted_driver_first():
    rng = np.random.default_rng(3)
    plan, blink, acts, pose = _series(rng)
    r = 0.4 * plan + 0.3 * blink + rng.normal(0, 0.02, plan.size)
    drivers = bc.residual_drivers(r, plan, acts, pose, top=5)
    name, value = next(iter(drivers.items()))
    assert name == "target eyeBlinkLeft" and value > 0.9
    assert "plan browInnerUp" not in drivers           # regressed out: its residual share is 0
    r2 = 0.4 * plan - 0.02 * pose[:, 1] + rng.normal(0, 0.01, plan.size)
    assert next(iter(bc.residual_drivers(r2, plan, acts, pose, top=3))) == "target yaw"


def test_chain_reports_a_negative_leak_of_the_target():
    rng = np.random.default_rng(5)
    n = 120
    s = {k: rng.uniform(0, 1, n) for k in ("FL(S) browInnerUp", "FL(T) browInnerUp")}
    s["capture browInnerUp"] = s["FL(S) browInnerUp"] * 1.2 + rng.normal(0, 0.05, n)
    s["plan browInnerUp"] = s["capture browInnerUp"]
    s["FL(R) browInnerUp"] = 0.4 * s["plan browInnerUp"] - 0.2 * s["FL(T) browInnerUp"]
    for k in ("mesh brow height", "target mesh brow height", "FL(R) brow height",
              "FL(S) brow height", "target browInnerUp"):
        s[k] = rng.uniform(0, 1, n)
    for b in ("browOuterUp", "browDown"):
        for k in ("FL(S)", "FL(R)", "FL(T)", "capture", "plan"):
            s[f"{k} {b}"] = rng.uniform(0, 1, n)
    ch = bc.chain(s)
    assert ch["b plan ~ capture"]["r"] == pytest.approx(1.0)
    assert ch["a capture ~ FL(S)"]["std_ratio"] == pytest.approx(1.2, abs=0.05)
    assert ch["c partial FL(R) ~ FL(T) | plan"] < -0.99
    a, b, c = ch["c FL(R) = a + b plan + c FL(T)"]
    assert b == pytest.approx(0.4, abs=1e-6) and c == pytest.approx(-0.2, abs=1e-6)
