"""A simulated DSP: the protocol's far end, with a helicopter point-mass model, on a pty or TCP port.

``DspMachine`` (pure state machine + vehicle, injected time step) does what a DSP does; ``DspSimulator``
puts it on a real transport; ``python -m modules.dsp.sim`` (``cromat dsp-sim``) runs it as its own process.
"""

from modules.dsp.sim.faults import FaultInjector
from modules.dsp.sim.machine import DspMachine, DspParams
from modules.dsp.sim.server import DspSimulator, RecordedCommand, SimSnapshot
from modules.dsp.sim.transport import PtyEndpoint, TcpEndpoint
from modules.dsp.sim.vehicle import Vehicle, VehicleParams

__all__ = ["DspMachine", "DspParams", "DspSimulator", "FaultInjector", "PtyEndpoint", "RecordedCommand",
           "SimSnapshot", "TcpEndpoint", "Vehicle", "VehicleParams"]
