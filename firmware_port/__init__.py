"""What runs on the MCU: the ATmega328 heater firmware in integer arithmetic (no numpy in the control path)."""
