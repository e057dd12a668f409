"""The per-reading laws compiled for the ATmega328P and run in simavr: the referee of the Python port.

``src/`` holds the C of the laws as they would go into Marlin on an AVR (pid, bangbang,
fuzzy_pi, fuzzy_pid, thermistor, adc, softpwm), built with ``avr-gcc -mmcu=atmega328p -Os -Wall
-Werror``, tables in PROGMEM; ``harness/`` the simulated board's main loop, one glue file per law
and the shim on libsimavr. ``toolchain`` and ``build`` find the tools and build into a cache,
``sim`` drives simavr through the shim, ``laws`` pairs each C law with the Python port it mirrors,
``runner`` steps both and compares them, ``footprint`` measures flash, RAM and cycles, and
``controllers`` puts a compiled law in a twin's loop (``engine="avr"``).

Needs the Debian packages gcc-avr, avr-libc, binutils-avr, libsimavr-dev and gcc
(``toolchain.APT_PACKAGES``); without them ``toolchain.find_toolchain()`` raises ToolchainMissing.
"""
