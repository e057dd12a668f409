/*
 * bangbang.h: Marlin's heater control without PIDTEMP / PIDTEMPBED, the C of
 * firmware_port/marlin/bangbang.py. BED_LIMIT_SWITCHING (Configuration.h) makes the bed hold its
 * output inside +-(BED_HYSTERESIS - 1) degC.
 */
#ifndef BANGBANG_H
#define BANGBANG_H

#include <stdint.h>

#ifndef BED_LIMIT_SWITCHING
#define BED_LIMIT_SWITCHING 0
#endif

/* The bed's state, 1 byte: its output, kept between checks when limit switching. */
typedef struct {
	uint8_t output;
} bangbang_bed_t;

uint8_t bangbang_hotend(int16_t temp_q5, int16_t target_c);
void bangbang_bed_reset(bangbang_bed_t *bed);
uint8_t bangbang_bed(bangbang_bed_t *bed, int16_t temp_q5, int16_t target_c);

#endif
