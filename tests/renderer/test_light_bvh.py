"""Next event estimation through the light BVH, against estimators that do not use it.

The scene (tessera_tools.many_lights): 10,000 small one-sided emitters over a grey floor.
`path` with the BVH must converge to the same image as `path` choosing lights by power and
as the light tracer (which never uses next event estimation), and spend its samples better.
"""
import numpy as np
import pytest

from test_integrators import H, POWER, W, quadrant_means, render, welch
from tessera_tools.many_lights import build

pytestmark = pytest.mark.slow  # ~20 s of renders

SEEDS = 12
SPP = {"bvh": 256, "power": 1024, "light": 512}  # what each needs for 2 % power (per-sample noise differs)


@pytest.fixture(scope="module")
def runs():
    bvh, power = build(10000, res=W, light_selection="bvh"), build(10000, res=W, light_selection="power")
    assert bvh.uses_light_bvh and not power.uses_light_bvh
    assert build(10000, res=W).uses_light_bvh, "auto picks the BVH for 10,000 emitters"
    assert not build(15, res=W).uses_light_bvh, "auto keeps the power sampler below 16 emitters"
    return {"bvh": [quadrant_means(render(bvh, "path", seed, SPP["bvh"])) for seed in range(SEEDS)],
            "power": [quadrant_means(render(power, "path", seed, SPP["power"])) for seed in range(SEEDS)],
            "light": [quadrant_means(render(power, "light", seed, SPP["light"])) for seed in range(SEEDS)]}


@pytest.mark.parametrize("other", ["power", "light"])
def test_bvh_light_choice_converges_to_the_same_image(runs, other):
    """Welch t per quadrant and channel (Bonferroni over 24). Power: each of the 12
    statistics detects 2 % (asserted); the control, the BVH's means scaled 2 % away from
    the other's, is flagged on every statistic. A pmf that Sample and the MIS weights
    disagreed on, or a light wrongly given probability 0, would shift these means."""
    t, limit, detectable = welch(runs["bvh"], runs[other])
    assert (np.abs(t) < limit).all(), f"bvh vs {other} t:\n{t.round(2)}\nlimits:\n{limit.round(2)}"
    assert (detectable < POWER).all(), f"detectable relative differences:\n{detectable.round(4)}"
    a, b = np.array(runs["bvh"]), np.array(runs[other])
    t2, limit2, _ = welch(a * (1 + np.sign(a.mean(axis=0) - b.mean(axis=0)) * POWER), b)
    assert (np.abs(t2) > limit2).all(), f"bvh scaled by 2 % passes against {other}:\n{t2.round(2)}"


def test_bvh_light_choice_has_less_variance_per_sample(runs):
    """The spread of the quadrant means over seeds, per sample: at least 3 x smaller
    variance with the BVH than by power (measured ~8 x per pixel). A BVH that chose no
    better than power (variance ratio 1) fails."""
    var_bvh = np.array(runs["bvh"]).var(axis=0, ddof=1) * SPP["bvh"]
    var_power = np.array(runs["power"]).var(axis=0, ddof=1) * SPP["power"]
    ratio = np.median(var_power / var_bvh)
    assert ratio > 3.0, f"variance ratio power / bvh {ratio:.2f}"
