/*
 * fixed.h: the integer helpers of firmware_port/fixed.py, for avr-gcc (int is 16 bits, long 32,
 * long long 64; >> on a signed value is arithmetic, so it floors).
 *
 * Every value that can leave 16 bits is cast to a 32- or 64-bit type before the operation: on
 * the AVR an int16_t - int16_t is computed in 16-bit int and may overflow where Python's does not.
 */
#ifndef FIXED_H
#define FIXED_H

#include <stdint.h>

#define TEMP_FRAC_BITS 5 /* celsius_q5: int16 Q10.5, 1/32 degC (firmware_port/thermistor.py) */
#define TEMP_ONE (1 << TEMP_FRAC_BITS)

/* shr_round: (x + 2^(n-1)) >> n, rounding to nearest with halves toward +infinity (n >= 1). */
static inline int32_t shr_round_s32(int32_t x, uint8_t n)
{
	return (x + ((int32_t)1 << (n - 1))) >> n;
}

static inline int64_t shr_round_s64(int64_t x, uint8_t n)
{
	return (x + ((int64_t)1 << (n - 1))) >> n;
}

/* div_round: a / b rounded to nearest, halves away from zero (b > 0); C's / truncates. */
static inline int32_t div_round_s32(int32_t a, int32_t b)
{
	int32_t half = b / 2;
	return a >= 0 ? (a + half) / b : (a - half) / b;
}

/* Marlin's constrain(). */
static inline int32_t clamp_s32(int32_t x, int32_t lo, int32_t hi)
{
	return x < lo ? lo : x > hi ? hi : x;
}

static inline int64_t clamp_s64(int64_t x, int64_t lo, int64_t hi)
{
	return x < lo ? lo : x > hi ? hi : x;
}

/* Saturation into int16_t and int32_t. */
static inline int16_t sat_s16(int32_t x)
{
	return (int16_t)clamp_s32(x, INT16_MIN, INT16_MAX);
}

static inline int32_t sat_s32(int64_t x)
{
	return (int32_t)clamp_s64(x, INT32_MIN, INT32_MAX);
}

#endif
