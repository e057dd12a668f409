"""The Marlin 2.1 heater firmware as it runs on an ATmega328 board."""
