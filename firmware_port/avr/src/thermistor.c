/*
 * thermistor.c: raw ADC sum -> celsius_q5 by bisection over the table in flash (Marlin's
 * SCAN_THERMISTOR_TABLE in Marlin/src/module/temperature.cpp) and rounded integer interpolation
 * instead of Marlin's float: t0 + (raw - v0) * (t1 - t0) / (v1 - v0), the product at most
 * 16368 * 65535 < 2^31. Raw values outside the table read the first or last row.
 */
#include "thermistor.h"

#include <avr/pgmspace.h>

#include "fixed.h"
#include "thermistor_table.h" /* generated from thermistor.py B3950_TABLE: b3950_table[], B3950_ROWS */

_Static_assert(B3950_ROWS >= 2 && B3950_ROWS < 256, "the bisection indexes rows with a uint8_t");

#define ROW_RAW(i) ((int16_t)pgm_read_word(&b3950_table[i].raw))
#define ROW_TEMP(i) ((int16_t)pgm_read_word(&b3950_table[i].temp_q5))

int16_t thermistor_lookup_q5(int16_t raw)
{
	uint8_t lo = 0;
	uint8_t hi = B3950_ROWS;
	for (;;) {
		uint8_t mid = (uint8_t)((lo + hi) >> 1);
		if (mid == 0)
			return ROW_TEMP(0);
		if (mid == lo || mid == hi)
			return ROW_TEMP(B3950_ROWS - 1);
		int16_t v0 = ROW_RAW(mid - 1);
		int16_t v1 = ROW_RAW(mid);
		if (raw < v0) {
			hi = mid;
		} else if (raw > v1) {
			lo = mid;
		} else {
			int16_t t0 = ROW_TEMP(mid - 1);
			int32_t span_q5 = (int32_t)ROW_TEMP(mid) - t0;
			return (int16_t)(t0 + div_round_s32(((int32_t)raw - v0) * span_q5, (int32_t)v1 - v0));
		}
	}
}
