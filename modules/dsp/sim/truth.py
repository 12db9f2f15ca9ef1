"""The simulator's side of the truth link: every physics step, the aircraft's true state as one UDP datagram.

The lidar simulators (``modules.lidar_logger.sim --follow-udp PORT``) fly with it; the contract and why it is
not on the robot's bus: ``bbcs/contracts/vehicle_truth.py``. Sending never blocks the DSP loop: a full socket
buffer or nobody listening yet costs that datagram only (counted).
"""

from __future__ import annotations

import socket

from bbcs.contracts.vehicle_truth import VehicleTruth, encode_truth
from modules.dsp.sim.machine import DspMachine
from modules.dsp.sim.vehicle import wrap_deg


class TruthSender:
    """Sends ``VehicleTruth`` datagrams to ``host:port`` (loopback only)."""

    def __init__(self, host: str, port: int, time_scale: float) -> None:
        if host not in ("127.0.0.1", "localhost", "::1"):
            raise ValueError(f"the truth link stays on this machine: {host!r} is not a loopback address")
        self.address = (host, port)
        self.time_scale = time_scale
        self.sent = 0
        self.failed = 0
        self._sock = socket.socket(socket.AF_INET6 if ":" in host else socket.AF_INET, socket.SOCK_DGRAM)
        self._sock.setblocking(False)

    def truth(self, machine: DspMachine) -> VehicleTruth:
        st = machine.vehicle.state
        lat, lon, alt = machine.to_global(st.pos)
        par = machine.params
        pitch = max(-90.0, min(90.0, st.pitch))
        return VehicleTruth(seq=self.sent + self.failed, time_s=machine.time_s, time_scale=self.time_scale,
                            home=(par.home_lat, par.home_lon, par.home_alt), lat=float(lat), lon=float(lon),
                            alt=float(alt), vel_neu=(float(st.vel[0]), float(st.vel[1]), float(st.vel[2])),
                            roll=wrap_deg(st.roll), pitch=pitch, heading=wrap_deg(st.heading))

    def send(self, machine: DspMachine) -> None:
        data = encode_truth(self.truth(machine))
        try:
            self._sock.sendto(data, self.address)
            self.sent += 1
        except OSError:  # nobody bound yet (ECONNREFUSED from an earlier datagram), buffer full
            self.failed += 1

    def close(self) -> None:
        self._sock.close()
