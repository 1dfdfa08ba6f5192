"""The reference backend: Pinocchio's forward dynamics of B arm copies in a Python substep loop.

Per substep of ``h = 1 / sim_hz`` (semi-implicit Euler, the time-scaled units of
:mod:`envs.physics.model`: ``w = h v`` rad per substep, torques and gravity times ``h^2``)::

    tau = clip(b - kp_e q - kd_e w + g(q), -effort, effort)    # b: the command's constant part
    w'  = clip(w + ABA(q, w, tau), -w_max, w_max)
    q'  = q + w'

then the stops: a copy whose substep left the URDF joint limits or put a moving link below
``z = plane_margin`` (world frame, m) goes back to its last valid substep with ``w = 0``. Held
joints (``task.held_joints``) are welded at the start pose (``locked``: ABA on Pinocchio's
reduced model) or held by the PD (``pd``). The compliant contact (:class:`PlaneContact`, this
backend only) adds penalty forces at the links' deepest points. The equations, the Lipschitz
screen that skips provably clear checks, and the measurements are in
``results/dynamics/README.md``.
"""

from __future__ import annotations

import functools
import math
from typing import TYPE_CHECKING, Any

import numpy as np
import pinocchio as pin

import ur5kin
from envs.checks import validate
from envs.physics.model import (
    arm_model,
    clip,
    height_lipschitz,
    link_hulls,
    moving_link_heights,
    put_at_rest,
)
from ur5kin.checks import COUNT

if TYPE_CHECKING:
    from envs.spec import TaskSpec

CLEARANCE_BATCH = 192
"""Most configurations per :func:`ur5kin.link_heights` call: larger products go to
multithreaded OpenBLAS, measured far slower (results/dynamics/README.md)."""


class PlaneContact:
    """The compliant model's ground reaction: penalty forces at the links' deepest points.

    Forces and torques are in :class:`PinocchioDynamics`'s time-scaled units (``h^2`` times N
    and N m), velocities ``w = h v``; the equations are in ``results/dynamics/README.md``. One
    configuration at a time, through Pinocchio's kinematics and joint Jacobians (tested against a
    closed-form Jacobian and the contact potential's gradient).

    Parameters
    ----------
    task : TaskSpec
        ``contact_stiffness``, ``contact_damping``, ``contact_friction``, ``plane_margin``,
        ``base_height`` and ``sim_hz``.
    model : pinocchio.Model
        The arm's model (kinematics only are used).
    reduced : pinocchio.Model or None
        The model of the joints that move when the held joints are locked (``buildReducedModel``
        at the start pose), whose ABA gives the response; None when all six move.
    """

    def __init__(self, task: TaskSpec, model: pin.Model, reduced: pin.Model | None = None
                 ) -> None:
        h = task.sim_dt
        self.level = task.plane_margin - task.base_height
        """The plane z = plane_margin, as a height (m) above ``base_link``."""
        self.stiffness = task.contact_stiffness * h * h  # scaled k
        self.damping = task.contact_damping * h  # scaled c
        self.friction = task.contact_friction
        self.model, self.data = model, model.createData()
        self.hulls = link_hulls()
        self._columns = [np.ascontiguousarray(hull.T) for hull in self.hulls]  # (3, n_k)
        self._wrench = np.zeros(6)
        # no gravity: its ABA at rest is M(q)^-1 tau (of the moving joints' block when locked)
        self._free = pin.Model(model if reduced is None else reduced)
        self._free.gravity = pin.Motion.Zero()
        self._free_data = self._free.createData()
        self._moving = self._free.nv
        self._rest = np.zeros(self._moving)
        self._response = np.zeros(model.nv)  # locked columns stay 0
        self._w_max = arm_model(task).w_max

    def response(self, q: np.ndarray, tau: np.ndarray) -> np.ndarray:
        """The change ``M(q)^-1 tau`` of the scaled velocity ``w`` (rad per substep) that a scaled
        contact torque ``tau (6,)`` makes in one substep: Pinocchio's ABA on the model without
        gravity, at rest. Added after the velocity clip: the URDF velocity limits are the
        motors', and the ground's reaction is not bound by them (clipping it lets a joint
        at its limit drive a link through the plane). Locked joints take the reaction in their
        weld: their response is 0, the moving ones' ``M_ff^-1 tau_f``."""
        m = self._moving
        if m == len(tau):
            return pin.aba(self._free, self._free_data, q, self._rest, tau)
        self._response[:m] = pin.aba(self._free, self._free_data, q[:m], self._rest, tau[:m])
        return self._response

    def governor(self, w: np.ndarray) -> None:
        """Scale ``w (6,)`` in place, all joints alike, into the URDF velocity limits.

        After a contact's response the velocity may exceed them; scaling the whole vector keeps
        its direction (a point leaving the plane still leaves it, one entering enters no faster)
        and only lowers the kinetic energy, where a per-joint clip can do either.
        """
        excess = np.max(np.abs(w) / self._w_max)
        if excess > 1.0:
            w /= excess
            clip(w, -self._w_max, self._w_max, w)  # rounding: the division can leave 1 ulp over

    def torque(self, q: np.ndarray, w: np.ndarray, links: np.ndarray, out: np.ndarray
                   ) -> bool:
        """Scaled contact torque ``out (6,)`` of one configuration, through Pinocchio.

        Parameters
        ----------
        q : (6,) float, rad
        w : (6,) float, rad per substep (``h v``)
        links : list of int
            Moving links to test, 1 (shoulder_link) .. 6 (wrist_3_link); the others are known
            to be clear.
        out : (6,) float
            Overwritten with ``h^2 tau_c``.

        Returns
        -------
        active : bool
            Whether a contact force acted.
        """
        model, data, hulls, columns = self.model, self.data, self.hulls, self._columns
        k_s, c_s, mu, dot = self.stiffness, self.damping, self.friction, np.dot
        wrench = self._wrench
        pin.forwardKinematics(model, data, q)
        placements = data.oMi
        out.fill(0.0)
        active = jacobians = False
        for k in links:
            pose = placements[k].homogeneous  # (4, 4), link frame -> base_link
            heights = dot(pose[2, :3], columns[k - 1])
            i = heights.argmin()
            depth = self.level - heights[i] - pose[2, 3]
            if depth <= 0.0:
                continue
            if not jacobians:
                pin.computeJointJacobians(model, data, q)
                jacobians = True
            # the link's twist (v, omega) at its origin and the lever to the point, world axes
            J6 = pin.getJointJacobian(model, data, k, pin.LOCAL_WORLD_ALIGNED)
            vx, vy, vz, ox, oy, oz = dot(J6, w).tolist()
            lx, ly, lz = dot(pose[:3, :3], hulls[k - 1][i]).tolist()
            ux, uy, uz = vx + oy * lz - oz * ly, vy + oz * lx - ox * lz, vz + ox * ly - oy * lx
            normal = k_s * depth - c_s * uz
            if normal <= 0.0:
                continue
            speed = math.hypot(ux, uy)
            drag = min(mu * normal, c_s * speed)
            scale = drag / speed if speed > 0.0 else 0.0
            fx, fy = -scale * ux, -scale * uy
            # tau = J6^T (f, lever x f): the force as a wrench at the link's origin
            wrench[:] = (fx, fy, normal, ly * normal - lz * fy, lz * fx - lx * normal,
                         lx * fy - ly * fx)
            out += dot(wrench, J6)
            active = True
        return active

def _last_valid(invalid: np.ndarray) -> np.ndarray:
    """Per column of ``invalid (S+1, m) bool``, the index before its first True (S if none)."""
    first = np.argmax(invalid, axis=0)
    return np.where(invalid.any(axis=0), first - 1, invalid.shape[0] - 1)


class PinocchioDynamics:
    """B copies of the UR5 under the task's controller, advanced one control step at a time:
    the reference :class:`envs.physics.Dynamics` (its parameters and attributes), and the only
    backend of the compliant contact.

    Attributes
    ----------
    w : (B, 6) float, rad per substep
        The integrator's velocity ``h v``.
    height_bound : (B, 6) float, m, world z
        A lower bound of each moving link's height now (exact after a reset), kept valid by
        :func:`envs.physics.model.height_lipschitz`.
    depth_stop : (B,) bool
        Whether the last step fell back to the stop because a link would have ended deeper
        than ``contact_max_depth`` below the plane (``compliant`` only; always False under
        ``stop``, whose stops are all in ``contact``).

    One copy (B = 1) calls Pinocchio's ``aba`` and ``computeGeneralizedGravity`` directly;
    more go through ``abaInParallel`` and ``rneaInParallel`` on one thread
    (results/dynamics/README.md says why).
    """

    def __init__(self, task: TaskSpec, num_copies: int = 1) -> None:
        B = self.num_copies = COUNT("num_copies", num_copies)
        self.task = validate(task)
        S, h, n = task.substeps, task.sim_dt, task.n_joints
        base = ur5kin.load_model()
        # the time-scaled model: gravity * h^2, so that ABA returns h^2 * a (module docstring)
        self.model = pin.Model(base)
        self.model.gravity = pin.Motion(np.asarray(base.gravity.linear) * h * h,
                                        np.asarray(base.gravity.angular))
        self.data = self.model.createData()
        self._pool = pin.ModelPool(self.model, 1) if B > 1 else None
        self._tool_frame = self.model.getFrameId(ur5kin.TOOL_FRAME)
        arm = self.arm = arm_model(task)
        # locked held joints: Pinocchio's reduced model, joints free+1..6 welded at the start
        self._reduced = None
        if arm.free < 6:
            self._reduced = pin.buildReducedModel(
                self.model, list(range(arm.free + 1, 7)), np.asarray(task.start_q, float))
            self._reduced.gravity = self.model.gravity

        self._lipschitz = height_lipschitz()
        # no point of link k falls more than S w_max . R[:, k] within one step (after substep
        # s, |q_s - q_0| <= s w_max): links with more clearance than that skip the exact check
        self._plane_screen = task.plane_margin + S * (arm.w_max @ self._lipschitz)
        # likewise a joint farther than S w_max from its limits cannot pass them in one step
        self._limit_screen = arm.q_half - S * arm.w_max
        self._limit_flags = np.zeros(6, dtype=bool)
        # the compliant contact (None: the stop model); a substep is deeper than allowed, and
        # stops, below _stop_level
        self._contact = (PlaneContact(task, self.model, self._reduced)
                         if task.contact_model == "compliant" else None)
        self._stop_level = task.plane_margin - (0.0 if self._contact is None
                                                else task.contact_max_depth)
        self._touched = np.zeros(B, dtype=bool)  # a contact force acted in this step
        self._contact_tau = np.zeros(6)

        # Substep history of the rows x = [q, w, b] (w = h v; b the constant part of the
        # scaled torque within a step: kp q_ref of position control, the torque command, ...).
        # Row 0 is the step's start. With b in the row, the PD torque is one product:
        # tau = x @ gains = b - kp_e q - kd_e w.
        self._X = np.zeros((S + 1, B, 18))
        self._Q, self._W = self._X[..., :6], self._X[..., 6:12]
        self._X[..., 12:18] = arm.initial_bias(B)  # held joints: PD to the start (pd)
        self._command_bias = self._X[..., 12 : 12 + n]
        gains = np.zeros((18, 6))
        gains[:6] = -np.diag(arm.kp_eff)
        gains[6:12] = -np.diag(arm.kd_eff)
        gains[12:] = np.eye(6)
        self._gains = gains
        self._tau = np.zeros((B, 6))
        self._gravity_out = np.zeros((B, 6))
        self._accel_out = np.zeros((B, 6))
        self._zeros = np.zeros((B, 6))

        # the state is the last history row: a step starts by copying it to row 0
        self.q = self._Q[S]
        self.w = self._W[S]
        self.q[:] = arm.start_q
        self.v = np.zeros((B, 6))
        self.acceleration = np.zeros((B, 6))
        self.contact = np.zeros(B, dtype=bool)
        self.limit_stop = np.zeros(B, dtype=bool)
        self.depth_stop = np.zeros(B, dtype=bool)
        self.height_bound = np.tile(moving_link_heights(arm.start_q, task.base_height),
                                    (B, 1))  # (B, 6) lower bounds

        X = self._X[:, 0] if B == 1 else self._X  # 1-D rows for Pinocchio's single calls
        self._rows = [(X[s], X[s, ..., :6], X[s, ..., 6:12], X[s + 1, ..., :6],
                       X[s + 1, ..., 6:12]) for s in range(S)]
        one = 0 if B == 1 else slice(None)
        self._tau_row, self._zeros_row = self._tau[one], self._zeros[one]
        self._gravity, self._accel = self._kernels()

    # ------------------------------------------------------------------ Pinocchio kernels
    def _kernels(self) -> tuple[Any, Any]:
        """``gravity(q) -> h^2 g(q)`` and ``accel(q, w, tau) -> h^2 a`` for the copies' rows.

        One copy binds Pinocchio's single-configuration functions (``functools.partial`` adds
        no Python frame); more wrap the parallel ones, which write into preallocated arrays.
        """
        model, data = self.model, self.data
        if self._pool is None:
            gravity = functools.partial(pin.computeGeneralizedGravity, model, data)
            if self._reduced is None:
                return gravity, functools.partial(pin.aba, model, data)
            return gravity, self._locked_accel()
        pool, g_out, a_out, zeros = self._pool, self._gravity_out, self._accel_out, self._zeros

        def gravity(q: np.ndarray) -> np.ndarray:
            pin.rneaInParallel(1, pool, q.T, zeros.T, zeros.T, g_out.T)
            return g_out

        def accel(q: np.ndarray, w: np.ndarray, tau: np.ndarray) -> np.ndarray:
            pin.abaInParallel(1, pool, q.T, w.T, tau.T, a_out.T)
            return a_out

        return gravity, (accel if self._reduced is None else self._locked_accel())

    def _locked_accel(self) -> Any:
        """``accel(q, w, tau) -> h^2 a`` with the held joints locked: the reduced model's ABA
        for joints 1..free (its gravity is the whole arm's in the held pose, the generalized
        gravity of joints 1..free equals the full model's) and 0 for the locked joints, so
        their ``w`` stays 0 and they never move."""
        m, reduced = self.arm.free, self._reduced
        if self._pool is None:
            data, out = reduced.createData(), np.zeros(6)

            def accel_one(q: np.ndarray, w: np.ndarray, tau: np.ndarray) -> np.ndarray:
                out[:m] = pin.aba(reduced, data, q[:m], w[:m], tau[:m])
                return out

            return accel_one
        B = self.num_copies
        pool, out = pin.ModelPool(reduced, 1), np.zeros((B, 6))
        qf, wf, tf, af = (np.zeros((B, m)) for _ in range(4))

        def accel_many(q: np.ndarray, w: np.ndarray, tau: np.ndarray) -> np.ndarray:
            np.copyto(qf, q[:, :m])
            np.copyto(wf, w[:, :m])
            np.copyto(tf, tau[:, :m])
            pin.abaInParallel(1, pool, qf.T, wf.T, tf.T, af.T)
            out[:, :m] = af
            return out

        return accel_many

    # ------------------------------------------------------------------ public API
    def reset(self, q: Any, index: Any = None) -> None:
        """:meth:`envs.physics.Dynamics.reset`."""
        sel = put_at_rest(self, q, index)
        self.depth_stop[sel] = False

    def step(self, command: np.ndarray) -> None:
        """:meth:`envs.physics.Dynamics.step`."""
        task, S = self.task, self.task.substeps
        # b of the controlled joints, in every row of the step (scaled: module docstring)
        np.multiply(self.arm.command_gain, command, out=self._command_bias)
        X = self._X
        X[0, :, :12] = X[S, :, :12]

        # Positional ``out`` arguments: keyword parsing costs ~10 % of a 6-vector ufunc call.
        dot, add, clip_ = np.dot, np.add, clip
        gains, tau = self._gains, self._tau_row
        effort, neg_effort = self.arm.effort, -self.arm.effort
        w_max, neg_w_max = self.arm.w_max, -self.arm.w_max
        gravity, accel = self._gravity, self._accel
        if not task.gravity_compensation:
            def gravity(q: np.ndarray) -> np.ndarray:
                return self._zeros_row
        near = None if self._contact is None else self._near_plane()
        contact = None if near is None or not len(near) else self._contact_forces(near)
        for x, q, w, q1, w1 in self._rows:
            dot(x, gains, tau)
            add(tau, gravity(q), tau)
            clip_(tau, neg_effort, effort, tau)
            add(w, accel(q, w, tau), w1)
            clip_(w1, neg_w_max, w_max, w1)
            if contact is not None:
                contact(q, w, w1)
            add(q, w1, q1)
        self._finish_step()

    # ------------------------------------------------------------------ compliant contact
    def _near_plane(self) -> np.ndarray:
        """Copies ``(m,) int`` that a contact force may reach within this step (the screen of
        ``__init__``); clears the step's contact flags."""
        self._touched[:] = False
        return np.flatnonzero((self.height_bound < self._plane_screen).any(axis=-1))

    def _reach_screen(self, r: int) -> Any:
        """``links(q) -> list``: the moving links (1-6) of copy r that may touch the plane at a
        substep configuration q of this step: the step's start clearance less ``|q - q_0| @ R``
        (:func:`height_lipschitz`) is below it. Changes the cost, never the answer."""
        q0, clear0 = self._Q[0, r].copy(), self.height_bound[r].copy()
        margin, lipschitz = self.task.plane_margin, self._lipschitz
        if (clear0 >= self._plane_screen).all():
            return lambda q: []
        buf, bound = np.empty(6), np.empty(6)
        subtract, absolute, dot, less = np.subtract, np.absolute, np.dot, np.less
        flags = np.empty(6, dtype=bool)

        def links(q: np.ndarray) -> list[int]:
            absolute(subtract(q, q0, buf), buf)
            subtract(clear0, dot(buf, lipschitz, bound), bound)
            if not less(bound, margin, flags).any():
                return []
            return [k + 1 for k in flags.nonzero()[0].tolist()]

        return links

    def _contact_forces(self, near: np.ndarray) -> Any:
        """``contact(q, w, w1)``: the compliant contact of one substep, added to its new velocity
        ``w1`` in place for the copies ``near`` the plane (:meth:`_near_plane`), copy by copy
        (Pinocchio's single-configuration calls; :meth:`PlaneContact.torque` of the links the
        screen of :meth:`_reach_screen` cannot rule out)."""
        add, tau_c, touched = np.add, self._contact_tau, self._touched
        torque, response, governor = (self._contact.torque, self._contact.response,
                                      self._contact.governor)
        screens = [(r, self._reach_screen(r)) for r in near.tolist()]
        one = self.num_copies == 1  # the rows are the copy's own (6,) arrays

        def contact(q: np.ndarray, w: np.ndarray, w1: np.ndarray) -> None:
            for r, reach in screens:
                qr, wr, w1r = (q, w, w1) if one else (q[r], w[r], w1[r])
                links = reach(qr)
                if links and torque(qr, wr, links, tau_c):
                    add(w1r, response(qr, tau_c), w1r)
                    governor(w1r)
                    touched[r] = True

        return contact

    # ------------------------------------------------------------------ stops
    def _finish_step(self) -> None:
        """Apply the joint-limit and plane stops, then publish the new state.

        Cheap screens decide which copies need the exact tests: a joint can pass its limit only
        if it starts within a step's travel (``S w_max``) of it, and a link can touch the plane
        only if its clearance is below a step's worth of fall (see ``__init__``). One copy
        takes a scalar path (array bookkeeping costs more than the tests on a batch of one);
        both paths are tested against each other.
        """
        if self.num_copies == 1:
            self._finish_one()
        else:
            self._finish_many()
        if self._contact is not None:  # the plane's stops are the depth bound's
            np.copyto(self.depth_stop, self.contact)
            np.logical_or(self.contact, self._touched, out=self.contact)
        W, S = self._W, self.task.substeps
        np.subtract(W[S], W[0], out=self.acceleration)
        self.acceleration *= self.arm.w_to_accel
        np.multiply(W[S], self.arm.w_to_v, out=self.v)

    def _finish_one(self) -> None:
        Q, W, S, level = self._Q[:, 0], self._W[:, 0], self.task.substeps, self._stop_level
        stop_limit = stop_plane = S  # the last valid substep
        if np.greater(np.abs(Q[0] - self.arm.q_mid), self._limit_screen, self._limit_flags).any():
            beyond = (np.abs(Q - self.arm.q_mid) > self.arm.q_half).any(axis=-1)  # (S+1,)
            if beyond.any():
                stop_limit = int(np.argmax(beyond)) - 1
        heights = None
        if (self.height_bound[0] < self._plane_screen).any():
            heights = moving_link_heights(Q, self.task.base_height)  # (S+1, 6): one call
            below = heights.min(axis=-1) < level
            below[0] = False  # the step's start state is clear by construction
            if below.any():
                stop_plane = int(np.argmax(below)) - 1
        stop = min(stop_limit, stop_plane)
        self.contact[0] = stop < S and stop == stop_plane
        self.limit_stop[0] = stop < S and stop == stop_limit
        if stop < S:
            Q[S] = Q[stop]  # back to the last valid substep ...
            W[S] = 0.0  # ... and stopped dead
        if heights is not None:
            self.height_bound[0] = heights[stop]
        else:  # link heights change by at most |dq| @ R (height_lipschitz)
            self.height_bound[0] -= np.abs(Q[S] - Q[0]) @ self._lipschitz

    def _finish_many(self) -> None:
        Q, W, S, B = self._Q, self._W, self.task.substeps, self.num_copies
        stop_limit = stop_plane = None  # per copy: the last valid substep, S if none failed
        if np.greater(np.abs(Q[0] - self.arm.q_mid), self._limit_screen).any():
            beyond = (np.abs(Q - self.arm.q_mid) > self.arm.q_half).any(axis=-1)  # (S+1, B)
            if beyond.any():
                stop_limit = _last_valid(beyond)
        risky = (self.height_bound < self._plane_screen).any(axis=-1)
        heights = None
        if risky.any():
            idx = np.flatnonzero(risky)
            per_call = max(1, CLEARANCE_BATCH // (S + 1))  # copies per link_heights call
            heights = np.concatenate([moving_link_heights(Q[:, idx[i : i + per_call]],
                                                          self.task.base_height)
                                      for i in range(0, len(idx), per_call)], axis=1)
            below = heights.min(axis=-1) < self._stop_level
            below[0] = False  # the step's start state is clear by construction
            if below.any():
                stop_plane = np.full(B, S)
                stop_plane[idx] = _last_valid(below)
        stop = np.full(B, S)
        for part in (stop_limit, stop_plane):
            if part is not None:
                np.minimum(stop, part, out=stop)
        stopped = stop < S
        np.logical_and(stopped, stop == (S if stop_plane is None else stop_plane),
                       out=self.contact)
        np.logical_and(stopped, stop == (S if stop_limit is None else stop_limit),
                       out=self.limit_stop)
        if stopped.any():
            rows = np.flatnonzero(stopped)
            Q[S, rows] = Q[stop[rows], rows]  # back to the last valid substep ...
            W[S, rows] = 0.0  # ... and stopped dead
        # link heights change by at most |dq| @ R (height_lipschitz): new lower bounds, or the
        # exact heights where they were just computed
        self.height_bound -= np.abs(Q[S] - Q[0]) @ self._lipschitz
        if heights is not None:
            self.height_bound[idx] = heights[stop[idx], np.arange(len(idx))]

    # ------------------------------------------------------------------ kinematics
    def tool_positions(self, out: np.ndarray) -> np.ndarray:
        """Write tool0's world position ``(B, 3)`` m (base at (0, 0, base_height)) into ``out``."""
        if self._pool is None:
            pin.forwardKinematics(self.model, self.data, self.q[0])
            out[0] = pin.updateFramePlacement(self.model, self.data, self._tool_frame).translation
        else:
            out[:] = ur5kin.fk(self.q)
        return ur5kin.to_world(out, self.task.base_height, out=out)
