/*
 * bangbang.c: full power below target, nothing above (Marlin 2.1.x Marlin/src/module/temperature.cpp
 * manage_hotends() without PIDTEMP and manage_heated_bed() without PIDTEMPBED).
 */
#include "bangbang.h"

#include "fixed.h"

#define BANG_MAX 255
#define MAX_BED_POWER 255
#define BED_HYSTERESIS_C 2
#define BED_BAND_Q5 ((int32_t)(BED_HYSTERESIS_C - 1) * TEMP_ONE)

uint8_t bangbang_hotend(int16_t temp_q5, int16_t target_c)
{
	return temp_q5 < (int32_t)target_c * TEMP_ONE ? BANG_MAX : 0;
}

void bangbang_bed_reset(bangbang_bed_t *bed)
{
	bed->output = 0;
}

uint8_t bangbang_bed(bangbang_bed_t *bed, int16_t temp_q5, int16_t target_c)
{
	int32_t target_q5 = (int32_t)target_c * TEMP_ONE;
#if BED_LIMIT_SWITCHING
	if (temp_q5 > target_q5 + BED_BAND_Q5)
		bed->output = 0;
	else if (temp_q5 < target_q5 - BED_BAND_Q5)
		bed->output = MAX_BED_POWER;
#else
	bed->output = temp_q5 < target_q5 ? MAX_BED_POWER : 0;
#endif
	return bed->output;
}
