"""pyserial URL handlers: ``twin://`` (protocol_twin.py), registered when ``protocol`` is imported."""

import serial

if __name__ not in serial.protocol_handler_packages:
    serial.protocol_handler_packages.append(__name__)
