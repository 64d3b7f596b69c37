"""Control of the multi-axis polariscope rig (docs/physics.md section 7) and its simulated twin.

Importing this package registers the simulated instruments with pyserial
(``ell14sim://``, ``aptsim://``), so a driver opens a simulated device and a
real one (``/dev/ttyUSB0``) the same way.
"""
import serial

if "mi_nest.rig.sim" not in serial.protocol_handler_packages:
    serial.protocol_handler_packages.append("mi_nest.rig.sim")
