"""Marlin 2.1.x compile-time constants for an AVR board with a hotend and a bed.

Sources (Marlin 2.1.x): HAL/AVR/timers.h,
module/temperature.h/.cpp, module/thermistor/thermistors.h, Configuration.h,
Configuration_adv.h.
"""

from fractions import Fraction

# Timing (Marlin 2.1.x Marlin/src/HAL/AVR/timers.h and module/temperature.cpp Temperature::isr()). The ISR runs on Timer0 compare A: 16 MHz / 64 / 256.
ISR_HZ = Fraction(16_000_000, 64 * 256)  # 976.5625 Hz exactly
ISR_PERIOD_S = 1 / ISR_HZ  # 1.024 ms
TEMP_TIMER_FREQUENCY = (16_000_000 + 0x2000) // 0x4000  # 977, Marlin's nominal integer
OVERSAMPLENR = 16
MIN_ADC_ISR_LOOPS = 10
ACTUAL_ADC_SAMPLES = MIN_ADC_ISR_LOOPS  # hotend + bed: SensorsReady = 5 < 10
TICKS_PER_READING = OVERSAMPLENR * ACTUAL_ADC_SAMPLES  # 160 ISRs = 0.16384 s
PID_DT_S = Fraction(OVERSAMPLENR * ACTUAL_ADC_SAMPLES, TEMP_TIMER_FREQUENCY)  # 160/977 s

# Soft PWM (Marlin 2.1.x Marlin/src/module/temperature.cpp Temperature::isr() SoftPWM): 7-bit, one period is 127 ISRs.
SOFT_PWM_PERIOD_TICKS = 127
SOFT_PWM_MAX = 127

# PID (Marlin 2.1.x Marlin/src/module/temperature.h PID_t::get_pid_output()).
PID_MAX = 255
BANG_MAX = 255
MAX_BED_POWER = 255
PID_FUNCTIONAL_RANGE_C = 10
PID_K1 = Fraction(95, 100)
DEFAULT_KP, DEFAULT_KI, DEFAULT_KD = 22.20, 1.08, 114.00
DEFAULT_BED_KP, DEFAULT_BED_KI, DEFAULT_BED_KD = 10.00, 0.023, 305.4

# Bang-bang bed (Marlin 2.1.x Marlin/src/module/temperature.cpp manage_heated_bed()).
BED_CHECK_INTERVAL_MS = 5000
BED_HYSTERESIS_C = 2

# Temperature limits (Marlin 2.1.x Marlin/src/module/temperature.cpp tr_state_machine_t, HeaterWatch, _temp_error()).
HEATER_0_MINTEMP_C, HEATER_0_MAXTEMP_C = 5, 275
BED_MINTEMP_C, BED_MAXTEMP_C = 5, 150
HOTEND_OVERSHOOT_C = 15
BED_OVERSHOOT_C = 10

# Thermal protection (Marlin 2.1.x Marlin/src/module/temperature.cpp tr_state_machine_t, HeaterWatch, _temp_error()).
THERMAL_PROTECTION_PERIOD_S, THERMAL_PROTECTION_HYSTERESIS_C = 40, 4
WATCH_TEMP_PERIOD_S, WATCH_TEMP_INCREASE_C = 40, 2
THERMAL_PROTECTION_BED_PERIOD_S, THERMAL_PROTECTION_BED_HYSTERESIS_C = 20, 2
WATCH_BED_TEMP_PERIOD_S, WATCH_BED_TEMP_INCREASE_C = 60, 2
TEMP_HYSTERESIS_C = 3
TEMP_BED_HYSTERESIS_C = 3

# M303 (Marlin 2.1.x Marlin/src/module/temperature.cpp Temperature::PID_autotune()).
MAX_OVERSHOOT_PID_AUTOTUNE_C = 30
MAX_CYCLE_TIME_PID_AUTOTUNE_MIN = 20
PREHEAT_1_TEMP_HOTEND_C = 180
PREHEAT_1_TEMP_BED_C = 70

# The E axis (Marlin 2.1.x Configuration.h DEFAULT_AXIS_STEPS_PER_UNIT, DEFAULT_MAX_FEEDRATE): the
# stepper position MPC's filament feed-forward reads, and the speed beyond which it takes a jump.
E_STEPS_PER_MM = 500
E_MAX_FEEDRATE_MM_S = 25


def ticks_to_ms(ticks: int) -> int:
    """Arduino ``millis()`` after ``ticks`` Timer0 overflows: 1 ms + 3/125 ms per tick."""
    return ticks * 128 // 125


def ms_to_ticks(ms: int) -> int:
    """The first tick count at which ``millis()`` has reached ``ms``."""
    return (ms * 125 + 127) // 128
