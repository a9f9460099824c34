"""Step control of the frame loop (cloth.simulation): every implicit step is checked before it is
kept, and a step that fails is undone and taken again as two of half its length.

A mixin of :class:`cloth.simulation.Simulation`, not functions taking the simulation: its methods
read and write the stepping state the frame loop owns (``dt``, ``_frame_dt``, the tick counters,
``_substep``, the solver's warm start ``last_dv``, ``last_energy``, ``_step_gave_up``), call the
frame loop's own ``step`` and ``untangle`` through ``self`` (so that a test that replaces
``Simulation._implicit_step`` or ``Simulation.untangle`` replaces them here too), and are called
as ``sim._controlled_step(...)`` and ``sim.step_failure(...)``. The class pickled in checkpoints
stays ``cloth.simulation.Simulation``; a mixin has no state of its own, so no instance of a new
class is pickled. :mod:`cloth.simulation` re-exports the constants and :class:`SimulationDiverged`.
"""

from __future__ import annotations

import numpy as np

from cloth.core.records import STEP_RECORD

# Step control. A step whose result fails a check (STEP_CHECKS) is undone (the state before it
# restored) and taken again as two steps of half its length, each checked the same way, at most
# MAX_STEP_HALVINGS times in a row: down to a step of dt / 16. A step that still fails then ends
# the run (SimulationDiverged), except a collision pass that gave up: at the finest step it is
# accepted and the cloth untangled before the next step, as without step control.
MAX_STEP_HALVINGS = 4
# A step may not raise the free nodes' kinetic energy above KE_JUMP_FACTOR times the energy the
# cloth had to move with at its start: its kinetic energy, its elastic (membrane and bending)
# energy, which a step may release into motion, and a floor, its mass moving at
# KE_FLOOR_SPEED_M_S (so that a cloth at rest may start to fall and a body may strike it).
# Implicit Euler dissipates: gravity, the handles and the obstacles are the only sources, and none
# multiplies that energy tenfold in a step of a frame or less; one bad hinge did (issue 32: a
# dancer's bending gradient went from 0.42 to 147 N in one step, and the cloth to 595 m/s within
# the frame). Without the elastic energy in the budget, a stiff sheet (100 x cotton, the stability
# suite's stiff_material) releasing 47 J of membrane energy into 1.7 J of motion was a jump.
KE_JUMP_FACTOR = 10.0
KE_FLOOR_SPEED_M_S = 1.0


class SimulationDiverged(RuntimeError):
    """A step failed its checks (non-finite state, a node over the speed limit, a jump of the
    kinetic energy) at every halving of its length that step control allows. `frame` is the frame
    it happened in and `rejected` what step control did in it, by STEP_RECORD column (that frame
    has no record: the run's summary counts it from here; dt_min_s is the last step tried)."""

    def __init__(self, message: str, frame: int | None = None, rejected: dict | None = None):
        super().__init__(message)
        self.frame = frame
        self.rejected = dict(rejected or {})


class StepControl:
    """Step control: a step taken (:meth:`_controlled_step`), checked (:meth:`step_failure`) and,
    if it fails, undone (:meth:`_save_step_state`, :meth:`_restore_step_state`) and taken again
    as two of half its length. Part of :class:`cloth.simulation.Simulation` (module docstring)."""

    def _controlled_step(self, halvings: int, timings: dict, stats: dict) -> None:
        """One step of the frame's step / 2**halvings under step control: taken, checked
        (:meth:`step_failure`) and, if it fails, undone and taken as two steps of half the length.
        Counts the rejections into `stats` (steps_rejected, steps_rejected_<check>, dt_min_s)."""
        self.dt = self._frame_dt / 2 ** halvings
        self._step_ticks = 2 ** (MAX_STEP_HALVINGS - halvings)
        for handle in self.scene.handles:  # take hold, pin, let a spring fade, let go (Handle.update) at the
            # step's start; idempotent, so a step taken again finds the phase it had
            handle.update(self.mesh.node_x, self.mesh.node_pinned, self.time)
        saved = self._save_step_state()
        self.step(timings, stats)
        failure = self.step_failure(saved["kinetic_energy"])
        finest = halvings == MAX_STEP_HALVINGS
        if failure is not None and not (finest and failure == "collisions"):
            stats["steps_rejected"] += 1
            stats[f"steps_rejected_{failure}"] += 1
            if finest:
                raise SimulationDiverged(
                    f"frame {self.frame + 1}: {self._failure_message(failure)} at t = {self.time:.4f} s, in a step "
                    f"of {self.dt:.3g} s taken again {MAX_STEP_HALVINGS} times at half the length "
                    f"(MAX_STEP_HALVINGS)", frame=self.frame + 1,
                    rejected={**{k: stats[k] for k in STEP_RECORD if k.startswith("steps_rejected")},
                              "dt_min_s": self.dt})
            self._restore_step_state(saved)
            for _ in range(2):
                self._controlled_step(halvings + 1, timings, stats)
            return
        self._substep += 1
        stats["dt_min_s"] = min(stats["dt_min_s"], self.dt)
        if self.stages.untangle and self._step_gave_up:
            # a collision pass gave up at the finest step: the cloth may now cross itself or a
            # body. Untangled before the next step, whose collision pass needs a clean start (a
            # fixed dress kept 12 such crossings for 165 frames; untangled only at the next
            # frame's start, frames 335-337 of its dance still ended crossing)
            self._timed(timings, "collisions.untangle", self.untangle, stats)

    def _free_kinetic_energy(self) -> tuple[float, float]:
        """(kinetic energy of the free nodes in J, their mass in kg)."""
        mesh = self.scene.mesh
        free = ~mesh.node_pinned
        m = mesh.node_m[free]
        v = mesh.node_v[free]
        return float(0.5 * np.sum(m * np.einsum("ij,ij->i", v, v))), float(m.sum())

    def _save_step_state(self) -> dict:
        """What a step changes, to undo it (positions, velocities, pins, the time, the warm start)."""
        mesh = self.scene.mesh
        return {"node_x": mesh.node_x.copy(), "node_v": mesh.node_v.copy(), "node_pinned": mesh.node_pinned.copy(),
                "time": self.time, "ticks": self._ticks, "last_dv": self.last_dv, "last_energy": self.last_energy,
                "steps_taken": self.steps_taken, "kinetic_energy": self._free_kinetic_energy()}

    def _restore_step_state(self, saved: dict) -> None:
        mesh = self.scene.mesh
        mesh.node_x[:] = saved["node_x"]
        mesh.node_v[:] = saved["node_v"]
        mesh.node_pinned[:] = saved["node_pinned"]
        self.time, self._ticks, self.steps_taken = saved["time"], saved["ticks"], saved["steps_taken"]
        self.last_dv, self.last_energy = None, saved["last_energy"]  # a failed solve is no warm start
        if self.stages.obstacle_contact:
            self.obstacle_set.set_time(self.time)

    def step_failure(self, kinetic_energy_before: tuple[float, float]) -> str | None:
        """The first of STEP_CHECKS the step just taken fails, or None. `kinetic_energy_before`:
        (J, kg) of the free nodes before it (:meth:`_free_kinetic_energy`)."""
        mesh = self.scene.mesh
        if not (np.all(np.isfinite(mesh.node_x)) and np.all(np.isfinite(mesh.node_v))):
            return "non_finite"
        if len(mesh.node_v) and float(np.max(np.einsum("ij,ij->i", mesh.node_v, mesh.node_v))) > self.max_speed ** 2:
            return "speed"
        if self._free_kinetic_energy()[0] > self._kinetic_energy_bound(kinetic_energy_before):
            return "kinetic_energy"
        if self._step_gave_up:
            return "collisions"
        return None

    def _kinetic_energy_bound(self, kinetic_energy_before: tuple[float, float]) -> float:
        """J: KE_JUMP_FACTOR x (the free nodes' kinetic energy before the step + the elastic energy
        at its start + their mass at KE_FLOOR_SPEED_M_S)."""
        ke_before, mass = kinetic_energy_before
        energy = self.last_energy  # the implicit step's, at the step's start
        elastic = max(float(energy.get("membrane", 0.0) + energy.get("bending", 0.0)), 0.0)
        return KE_JUMP_FACTOR * (ke_before + elastic + 0.5 * mass * KE_FLOOR_SPEED_M_S ** 2)

    def _failure_message(self, failure: str) -> str:
        mesh = self.scene.mesh
        if failure == "non_finite":
            return "non-finite node positions or velocities"
        if failure == "speed":
            speed = float(np.sqrt(np.max(np.einsum("ij,ij->i", mesh.node_v, mesh.node_v))))
            return f"node speed {speed:.3g} m/s exceeds max_speed = {self.max_speed:g} m/s"
        ke, _ = self._free_kinetic_energy()
        return (f"kinetic energy {ke:.3g} J more than KE_JUMP_FACTOR = {KE_JUMP_FACTOR:g} times the kinetic and "
                f"elastic energy before the step (with a floor of the cloth's mass at {KE_FLOOR_SPEED_M_S:g} m/s)")
