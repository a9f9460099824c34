"""`seed` perturbs the character scenes reproducibly: two seeds give two trajectories, one seed
gives the same one bit for bit, and the perturbation is the documented sub-millimetre jitter of
the garment's free nodes (the pinned ones stay where the garment puts them)."""

import numpy as np
import pytest
from helpers import COTTON

from cloth.scenes.registry import CHARACTER_JITTER, build_scene
from cloth.simulation import Simulation

FRAMES = 3
# A normal deviate beyond 6 sigma has odds of 1e-9 per draw: no node of a few hundred moves
# farther than 6 x the jitter on an axis.
SIGMAS = 6.0
SMALL = {"solo_dancer": dict(resolution=12), "karate": dict(resolution=12)}


def final_positions(name: str, seed: int, **params) -> np.ndarray:
    sim = Simulation(build_scene(name, COTTON, seed=seed, **SMALL[name], **params))
    for _ in range(FRAMES):
        sim.advance_frame()
    return sim.mesh.node_x.copy()


@pytest.mark.parametrize("name", list(SMALL))
def test_two_seeds_give_two_trajectories_and_one_seed_the_same(name):
    a, again, b = final_positions(name, 0), final_positions(name, 0), final_positions(name, 1)
    assert np.array_equal(a, again)
    assert np.abs(a - b).max() > 0.0


@pytest.mark.parametrize("name", list(SMALL))
def test_the_seed_moves_only_the_free_nodes_and_by_less_than_a_millimetre(name):
    quiet = build_scene(name, COTTON, jitter=0.0, **SMALL[name]).mesh
    scenes = [build_scene(name, COTTON, seed=s, **SMALL[name]) for s in (0, 1)]
    for scene in scenes:
        moved = scene.mesh.node_x - quiet.node_x
        pinned = scene.mesh.node_pinned
        assert pinned.any() and np.all(moved[pinned] == 0.0)
        assert 0.0 < np.abs(moved[~pinned]).max() < SIGMAS * CHARACTER_JITTER < 1e-3
    assert not np.array_equal(scenes[0].mesh.node_x, scenes[1].mesh.node_x)
    # without jitter the seed changes nothing
    assert np.array_equal(build_scene(name, COTTON, jitter=0.0, seed=3, **SMALL[name]).mesh.node_x, quiet.node_x)


def test_a_negative_jitter_is_refused():
    with pytest.raises(ValueError, match="jitter must be >= 0"):
        build_scene("solo_dancer", COTTON, jitter=-1e-4, resolution=12)
