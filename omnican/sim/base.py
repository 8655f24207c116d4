"""A simulated omni base: one simulated drive per node of a config, plus ground truth.

The drives are made as the config reads them (:mod:`omnican.sim.wiring`); the true pose
is integrated from their *physical* wheel motion through the base's true kinematics
(:mod:`omnican.sim.truth`).

Where the drives run: on a housekeeping thread and python-can's Notifier (real time), on
the simulated clock (lock-step), or, ``stepped``, on the control loop of a base opened in
this process on the same channel (:mod:`omnican.io.stepped`): their timers before each
cycle, the cycle's frames after it, and their own threads only before the loop starts
and after it ends. Stepped drives are as steady as the loop, whatever else the process
and the machine do: beside a browser, threads at normal priority in a process whose loop
runs at real-time priority fell behind by more than a heartbeat-consumer time. Their
consumer still watches the host honestly: a loop that stalls finds its drives' timers run
first, with the host's heartbeat as late as it was (EMCY 8130h), as real drives would.
A simulator serving another process (``omnican sim``) has no loop to follow: its threads
take the loop's real-time class instead (``rt_priority``).
"""

from __future__ import annotations

import logging
import math
import threading
import time
from collections.abc import Mapping, Sequence
from typing import Any

import can
import canopen
import numpy as np
import numpy.typing as npt

from omnican.chassis.realtime import realtime_refusal
from omnican.clock import REAL_TIME, Clock
from omnican.config import ChassisConfig
from omnican.core.kinematics import OmniKinematics, Twist
from omnican.core.odometry import Pose2D
from omnican.errors import BusError, ConfigError
from omnican.io import stepped as stepped_io
from omnican.io.bus_watch import describe_open_error
from omnican.io.lockstep import LockstepBus, listeners_receiver
from omnican.io.network import Network
from omnican.sim.drive import SimulatedDrive
from omnican.sim.gyro import SimulatedGyro, attach_gyro
from omnican.sim.lss import SimLss
from omnican.sim.scheduler import SimScheduler
from omnican.sim.slip import SimSlip
from omnican.sim.truth import GroundTruth
from omnican.sim.wiring import health_wiring, make_drive

logger = logging.getLogger(__name__)

TICK_S = 0.002  # the drives' housekeeping period in real time
DRAIN_LIMIT = 1024  # frames handled per control cycle when stepped (the rest: the next)


class _ReceiveErrors(can.Listener):
    """Takes python-can's receive errors (reported once per outage) so the Notifier
    thread lives on; pauses a little so a permanently failing receive does not spin."""

    def __init__(self) -> None:
        self._reported = False

    def on_message_received(self, msg: can.Message) -> None:
        self._reported = False

    def on_error(self, exc: Exception) -> None:
        if not self._reported:
            self._reported = True
            logger.warning("simulated drives: receive failed: %s", exc)
        time.sleep(0.05)

    def stop(self) -> None:
        pass


def _open_network(bus_kwargs: dict[str, Any], clock: Clock) -> Network:
    """The simulated drives' network on ``bus_kwargs``' bus: in lock-step, an in-process
    channel of that name (ConfigError for another interface); else the bus itself
    (BusError, in one line, if it cannot be opened)."""
    network = Network()
    network.NOTIFIER_CYCLE = 0.02  # bounds how long close() waits for the Notifier
    if clock.lockstep:
        channel = bus_kwargs.get("channel")
        if bus_kwargs.get("interface", "virtual") != "virtual" or not channel:
            raise ConfigError("lock-step simulation runs on an in-process channel: the "
                              "bus must be interface 'virtual' with a channel")
        lockstep = LockstepBus(str(channel), clock)
        lockstep.set_receiver(network.lockstep_receiver(), network.lockstep_frame_receiver())
        network.bus = lockstep
        return network
    # A receive error (an interface that went down) is handled, not the end of the
    # simulator's Notifier: it keeps serving when the link returns.
    network.listeners.append(_ReceiveErrors())  # type: ignore[arg-type]
    try:
        network.connect(**bus_kwargs)
    except Exception as exc:
        raise BusError(describe_open_error(bus_kwargs, exc)) from None
    return network


class SimulatedBase:
    """Simulated drives for every wheel of ``cfg`` on the configured bus.

    Use :meth:`from_config`; it is a context manager that owns the bus, the network
    and the housekeeping thread."""

    def __init__(
        self,
        cfg: ChassisConfig,
        network: canopen.Network,
        scheduler: SimScheduler,
        drives: list[SimulatedDrive],
        wheel_axes: list[tuple[SimulatedDrive, int]],
        true_kinematics: OmniKinematics,
        counts_per_metre: npt.NDArray[np.float64],
        clock: Clock = REAL_TIME,
    ) -> None:
        self.cfg = cfg
        self.clock = clock
        self.network = network
        self.scheduler = scheduler
        self.drives = drives
        self.wheel_axes = wheel_axes
        self.true_kinematics = true_kinematics
        self._truth = GroundTruth(wheel_axes, true_kinematics, counts_per_metre, clock)
        self._lock = threading.Lock()
        self._closed = False
        scheduler.add(self._truth.follow)
        self._channel: str | None = None  # offered to a base's loop on this channel
        self._rt_priority = 0
        #: why the drives' threads run at normal priority though ``rt_priority`` asked
        #: for real-time priority (None: they do run at it, or it was not asked)
        self.realtime_refused: str | None = None
        #: the drives run on a base's control loop now (``stepped``)
        self.stepping = False
        self._receive: Any = None
        self._last_tick = -math.inf
        #: the simulated IMU, with a CAN ``[imu]`` table (:mod:`omnican.sim.gyro`)
        self.gyro: SimulatedGyro | None = None
        self._gyro_task: object | None = None
        self.lss: SimLss | None = None  # LSS, memory and power (:mod:`omnican.sim.lss`)

    @classmethod
    def from_config(
        cls,
        cfg: ChassisConfig,
        *,
        bus: Mapping[str, Any] | None = None,
        true_kinematics: OmniKinematics | None = None,
        true_scale: float | Sequence[float] = 1.0,
        tick_s: float | None = None,
        drive_options: Mapping[int, Mapping[str, Any]] | None = None,
        clock: Clock | None = None,
        stepped: bool = False,
        rt_priority: int = 0,
        serials: Mapping[int, int] | None = None,
        unconfigured: bool = False,
        refuse_store: frozenset[int] = frozenset(),
        **options: Any,
    ) -> SimulatedBase:
        """Start simulated drives for ``cfg``.

        Args:
            cfg: the robot config (its ``bus`` section is used unless ``bus`` is given).
            true_kinematics: the real geometry, if it differs from the configured one.
            true_scale: real counts per metre / configured ``position_scale``, per wheel
                (a wheel worn smaller than configured has ``true_scale > 1``).
            tick_s: housekeeping period (heartbeats, timeouts, event TPDOs, the truth);
                default 2 ms, and in lock-step the control period where that is longer:
                a drive's housekeeping then runs once a control cycle, as fast as the
                host's cycles come, not five times (frames are answered when they
                arrive, whatever the period).
            drive_options: extra :class:`SimulatedDrive` arguments per node id.
            clock: :data:`~omnican.clock.REAL_TIME` (default: drives on a housekeeping
                thread, frames through the configured bus) or a
                :class:`~omnican.clock.SimClock`: lock-step, single-threaded, on an
                in-process channel named after the configured one (a
                :class:`~omnican.Chassis` opened with the same clock reaches it).
            stepped: in real time on a ``virtual`` channel, let the control loop of the
                first :class:`~omnican.Chassis` opened in this process on that channel run
                the drives (see the module docstring): what ``--sim`` does.
            rt_priority: the drives' threads run SCHED_FIFO at this priority (1-99)
                where the process may (:attr:`realtime_refused` says why not); 0: normal
                priority. What ``omnican sim`` does, with the config's
                ``chassis.rt_priority``, to keep up with a loop in another process.
            serials, unconfigured, refuse_store: the drives' LSS and memory, see
                :class:`~omnican.sim.lss.SimLss` (``omnican commission``).
            **options: :class:`SimulatedDrive` arguments for every drive
                (``encoder_noise``, ``slip``, ``frame_loss``, ``tau_s``, ...).
        """
        bus_kwargs = dict(bus if bus is not None else (cfg.bus or {}))
        scales = (list(true_scale) if isinstance(true_scale, Sequence)
                  else [float(true_scale)] * len(cfg.wheels))
        if len(scales) != len(cfg.wheels):
            raise ConfigError(f"true_scale has {len(scales)} values for {len(cfg.wheels)} wheels")
        clock = clock if clock is not None else REAL_TIME
        network = _open_network(bus_kwargs, clock)
        if tick_s is None:
            tick_s = max(TICK_S, 1.0 / cfg.chassis.rate_hz) if clock.lockstep else TICK_S
        scheduler = SimScheduler(tick_s, name="omnican-sim", clock=clock)
        drives: list[SimulatedDrive] = []
        try:
            by_node: dict[int, SimulatedDrive] = {}
            health = health_wiring(cfg, scales)
            opts: dict[int, dict[str, Any]] = {}
            for node_id, wheels in cfg.nodes().items():
                opts[node_id] = {**health[node_id], **options,
                                 **(drive_options or {}).get(node_id, {}), "clock": clock}
                by_node[node_id] = make_drive(network, node_id, wheels, scheduler,
                                              {**opts[node_id], "boot": not unconfigured})
                drives.append(by_node[node_id])
            wheel_axes = [(by_node[w.node_id], w.axis) for w in cfg.wheels]
            counts = np.array([w.position_scale * s for w, s in zip(cfg.wheels, scales,
                                                                     strict=True)])
            base = cls(cfg, network, scheduler, drives, wheel_axes,
                       true_kinematics or cfg.kinematics(), counts, clock)
            base.gyro, base._gyro_task = attach_gyro(
                cfg, network, scheduler, clock, lambda: base.true_pose, lambda: base.true_twist)
            if cfg.sim is not None and cfg.sim.slip is not None:  # [sim.slip]
                base._truth.slip = SimSlip.of(cfg.sim.slip)
            base.lss = SimLss(base, base._truth, lambda config_id, node_id: make_drive(
                network, node_id, cfg.nodes()[config_id], scheduler,
                {**opts[config_id], "boot": False}), serials, unconfigured, refuse_store)
        except BaseException:
            for d in drives:
                d.close()
            scheduler.close()
            network.disconnect()
            raise
        scheduler.start()
        if rt_priority and not clock.lockstep:
            base._rt_priority = rt_priority
            base._take_priority()
        if stepped and not clock.lockstep and bus_kwargs.get("interface") == "virtual" \
                and bus_kwargs.get("channel"):
            base._channel = str(bus_kwargs["channel"])
            stepped_io.offer(base._channel, base)
        logger.info("simulated base: nodes %s on %s", sorted(by_node), bus_kwargs)
        return base

    # ------------------------------------------------------------ truth

    @property
    def true_pose(self) -> Pose2D:
        """Ground-truth pose of the base (m, m, rad; theta continuous). While a base's
        loop runs the drives (``stepped``), another thread reads it as of the loop's last
        cycle: taking the drives' locks there could hold the loop up."""
        return self._truth.pose

    @property
    def true_twist(self) -> Twist:
        """Ground-truth body velocity now (m/s, m/s, rad/s); see :attr:`true_pose`."""
        return self._truth.twist

    def reset_truth(self, pose: Pose2D | None = None) -> None:
        self._truth.reset(pose)

    def set_battery(self, volts: float) -> None:
        """The battery feeding every drive's DC link is at ``volts`` from now on
        (nominal: 24 V); each drive's link sags below it under its motors' current."""
        if not (math.isfinite(volts) and volts >= 0):
            raise ValueError(f"a battery voltage is 0 or more, got {volts!r}")
        for d in self.drives:
            d.set_supply(volts)

    def estop(self, pressed: bool) -> None:
        """Press (True) or release the e-stop: it is wired to every drive's input and
        to their safe torque off (see :meth:`SimulatedDrive.estop`)."""
        for d in self.drives:
            d.estop(pressed)

    def power_cycle(self) -> None:
        """Every drive off and on: what it stored comes back (:meth:`SimLss.power_cycle`)."""
        if self.lss is not None:
            self.lss.power_cycle()

    def wheel_drive(self, wheel: int) -> tuple[SimulatedDrive, int]:
        """(drive, axis) that simulates wheel number ``wheel`` of the config."""
        return self.wheel_axes[wheel]

    # ------------------------------------------------------------ lifecycle

    def step(self, now: float) -> None:
        """Advance every simulated drive to ``now``: heartbeats, timeouts, event TPDOs
        (lock-step: the clock calls this every ``tick_s``)."""
        self.scheduler.step(now)

    def wait(self, seconds: float) -> None:
        """Let simulated time pass (in lock-step this runs the simulation)."""
        self.clock.sleep(seconds)

    # ------------------------------------------------ run by a base's loop (stepped)

    def begin(self) -> None:
        """A base's control loop runs the drives from now on (its thread calls this):
        the housekeeping thread and the Notifier stop; what reached the bus meanwhile
        waits for :meth:`drain`."""
        if self._closed:
            return
        network = self.network
        self.scheduler.pause()
        with network.send_lock:
            notifier, network.notifier = network.notifier, None
        if notifier is not None:
            notifier.stop(0.5)
        # Every listener, as the Notifier would (canopen's in one call on ours).
        self._receive = (network.lockstep_receiver() if isinstance(network, Network)
                         else listeners_receiver(network.listeners))
        self._last_tick = -math.inf
        self._truth.run_on(threading.get_ident())
        self.stepping = True
        logger.debug("simulated drives run on the control loop")

    def tick(self, now: float) -> None:
        """The drives' timers at ``now`` (at most once a housekeeping period): their
        heartbeats, their consumers of the host's, event TPDOs, boots; the truth."""
        if self.stepping and not self._closed and now - self._last_tick >= self.scheduler.period_s:
            self._last_tick = now
            self.scheduler.step(now)

    def drain(self) -> None:
        """Hand every frame that reached the drives' bus to them, at most
        :data:`DRAIN_LIMIT` (the rest wait for the next cycle)."""
        bus, receive = self.network.bus, self._receive
        if not self.stepping or self._closed or bus is None or receive is None:
            return
        for _ in range(DRAIN_LIMIT):
            msg = bus.recv(0)
            if msg is None:
                return
            receive(msg)

    def end(self) -> None:
        """The loop no longer runs the drives: their own threads again (with their
        priority), before the base's shutdown talks to them."""
        self.stepping = False
        self._truth.run_on(0)
        if self._closed:
            return
        network = self.network
        bus = network.bus
        if bus is not None:
            listeners: list[can.Listener] = network.listeners  # type: ignore[assignment]
            try:
                network.notifier = can.Notifier(bus, listeners, network.NOTIFIER_CYCLE)
            except Exception as exc:  # the bus is gone: nothing to receive
                logger.warning("simulated drives: receiving again failed: %s", exc)
        self.scheduler.resume()
        if self._rt_priority:
            self._take_priority()
        logger.debug("simulated drives run on their own threads")

    def _take_priority(self) -> None:
        """The housekeeping and receiving threads at ``rt_priority`` (SCHED_FIFO)."""
        ids = [self.scheduler.native_id]
        notifier = self.network.notifier
        ids += [getattr(t, "native_id", None) for t in getattr(notifier, "_readers", ())]
        refused = None
        for native_id in ids:
            if native_id:
                refused = realtime_refusal(self._rt_priority, native_id) or refused
        self.realtime_refused = refused

    def close(self) -> None:
        with self._lock:
            if self._closed:
                return
            self._closed = True
        self._truth.stop()
        if self._gyro_task is not None:
            self.clock.cancel(self._gyro_task)
        if self.lss is not None:
            self.lss.close()
        if self._channel is not None:
            stepped_io.withdraw(self._channel, self)
        self.scheduler.close()
        for d in self.drives:
            d.close()
        self.network.disconnect()

    def __enter__(self) -> SimulatedBase:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

