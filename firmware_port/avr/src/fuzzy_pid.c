/*
 * fuzzy_pid.c: seed 001's gain scheduler and PID, as firmware_port/fuzzy_pid.py FuzzyPid
 * computes it. The error and its change per sample are quantised onto [-3, 3] (Q8, saturated)
 * and fuzzified by 7 unit triangles NB..PB; the three 7x7 rule tables (Fig. 7, in flash) fire
 * output sets on [0, 3] by min-max; a sampled centroid (16 points a unit) gives each gain factor;
 * u = kp e + I + kd ec with I += ki e, I and u clamped to 0..255 (Q8).
 */
#include "fuzzy_pid.h"

#include <avr/pgmspace.h>
#include <stddef.h>

#include "fixed.h"
#include "fuzzy_pid_rules.h" /* generated from fuzzy_pid.py RULES: fuzzy_pid_rules[3][7][7] PROGMEM */

#define N_SETS 7
#define HALF 3 /* the ZO set; the input universe is [-3, 3] */
#define POS_BITS 8
#define POS_ONE (1 << POS_BITS)
#define POS_MAX (HALF << POS_BITS) /* 768 */
#define GRID 8                     /* output grid points per set step */
#define GRID_MAX ((N_SETS - 1) * GRID)
#define FACTOR_BITS 12
#define K_BITS 12
#define OUT_FRAC_BITS 8
#define OUT_MAX_Q8 ((int32_t)255 << OUT_FRAC_BITS)
#define POS_SHIFT (K_BITS + TEMP_FRAC_BITS - POS_BITS)
#define P_SHIFT (12 + FACTOR_BITS + TEMP_FRAC_BITS - OUT_FRAC_BITS)
#define I_SHIFT (24 + FACTOR_BITS + TEMP_FRAC_BITS - OUT_FRAC_BITS)
#define D_SHIFT (16 + FACTOR_BITS + TEMP_FRAC_BITS - OUT_FRAC_BITS)

typedef struct {
	uint8_t count;
	uint8_t set[2];
	uint16_t mu_q8[2];
} fired_t;

/* Quantisation onto the universe, Q8, saturated to [-3, 3]: an int64 product (<= 2^37). */
static int16_t position_q8(int16_t value_q5, uint32_t k_q12)
{
	return (int16_t)clamp_s64(shr_round_s64((int64_t)value_q5 * k_q12, POS_SHIFT), -POS_MAX, POS_MAX);
}

static void fuzzify(int16_t x_q8, fired_t *fired)
{
	uint8_t left = (uint8_t)((x_q8 + POS_MAX) >> POS_BITS); /* the set centred at or left of x */
	if (left > N_SETS - 1)
		left = N_SETS - 1;
	fired->count = 0;
	for (uint8_t k = left; k <= left + 1 && k < N_SETS; k++) {
		int16_t distance = x_q8 - ((int16_t)k - HALF) * POS_ONE;
		int16_t mu_q8 = POS_ONE - (distance < 0 ? -distance : distance);
		if (mu_q8 > 0) {
			fired->set[fired->count] = k;
			fired->mu_q8[fired->count] = (uint16_t)mu_q8;
			fired->count++;
		}
	}
}

/* Sampled centroid in Q12 units of [0, 3]. At grid point y only the output sets y / 8 and, between
 * two centres, the next one have a non-zero degree. y * mu <= 48 * 256 and the sum of the degrees
 * <= 49 * 256 fit 16 bits; num < 2^19; den >= 3.25 * 256 (some rule fires at >= 1/2). */
static int16_t centroid_q12(const uint16_t strength_q8[N_SETS])
{
	int32_t num = 0;
	uint16_t den = 0;
	for (uint8_t y = 0; y <= GRID_MAX; y++) {
		uint8_t j = y / GRID;
		uint8_t r = y % GRID;
		uint16_t shape = (uint16_t)(GRID - r) << (POS_BITS - 3);
		uint16_t mu_q8 = strength_q8[j] < shape ? strength_q8[j] : shape;
		if (r) {
			shape = (uint16_t)r << (POS_BITS - 3);
			uint16_t next = strength_q8[j + 1] < shape ? strength_q8[j + 1] : shape;
			if (next > mu_q8)
				mu_q8 = next;
		}
		num += (uint16_t)(y * mu_q8);
		den += mu_q8;
	}
	return (int16_t)div_round_s32(num * POS_ONE, den);
}

/* Gain factor Q12: the centroid (literal) or 1 + span (c - 1.5) / 1.5 (incremental). */
static int16_t factor_q12(const fuzzy_pid_config_t *config, int16_t c_q12)
{
	if (config->literal)
		return c_q12;
	int32_t offset = (int32_t)config->span_q4 * (c_q12 - (3 << (FACTOR_BITS - 1)));
	return (int16_t)((1 << FACTOR_BITS) + div_round_s32(offset, 24)); /* Q4 * Q12 / (1.5 * 16) */
}

static void infer_q12(const fuzzy_pid_config_t *config, int16_t e_q5, int16_t derr_q5, int16_t factors_q12[3])
{
	fired_t e, ec;
	fuzzify(position_q8(e_q5, config->ke_q12), &e);
	fuzzify(position_q8(derr_q5, config->kec_ps_q12), &ec);
	for (uint8_t table = 0; table < 3; table++) {
		uint16_t strength_q8[N_SETS] = {0, 0, 0, 0, 0, 0, 0};
		for (uint8_t i = 0; i < e.count; i++) {
			for (uint8_t j = 0; j < ec.count; j++) {
				uint8_t k = pgm_read_byte(&fuzzy_pid_rules[table][e.set[i]][ec.set[j]]);
				uint16_t mu = e.mu_q8[i] < ec.mu_q8[j] ? e.mu_q8[i] : ec.mu_q8[j];
				if (mu > strength_q8[k])
					strength_q8[k] = mu;
			}
		}
		factors_q12[table] = factor_q12(config, centroid_q12(strength_q8));
	}
}

void fuzzy_pid_reset(fuzzy_pid_state_t *pid)
{
	pid->i_q8 = 0;
	pid->e_prev_q5 = 0;
	pid->have_prev = 0;
}

int32_t fuzzy_pid_update_q8(fuzzy_pid_state_t *pid, const fuzzy_pid_config_t *config, int16_t temp_q5,
			    int16_t target_c, int16_t *factors_q12)
{
	int16_t f[3] = {0, 0, 0};
	int32_t out_q8 = 0;
	if (target_c == 0) {
		fuzzy_pid_reset(pid);
	} else {
		int16_t e_q5 = sat_s16((int32_t)target_c * TEMP_ONE - temp_q5);
		int16_t derr_q5 = pid->have_prev ? sat_s16((int32_t)e_q5 - pid->e_prev_q5) : 0;
		pid->e_prev_q5 = e_q5;
		pid->have_prev = 1;
		infer_q12(config, e_q5, derr_q5, f);
		/* kp_q12 * factor * e < 2^51: Q29 -> Q8 */
		int32_t p_q8 = (int32_t)shr_round_s64((int64_t)config->kp_q12 * f[0] * e_q5, P_SHIFT);
		/* ki_q24 * factor * e < 2^57: Q41 -> Q8; the sum is clamped (anti-windup) */
		int32_t di_q8 = (int32_t)shr_round_s64((int64_t)config->ki_q24 * f[1] * e_q5, I_SHIFT);
		pid->i_q8 = clamp_s32(pid->i_q8 + di_q8, 0, OUT_MAX_Q8);
		/* kd_q16 * factor * derr < 2^60: Q33 -> Q8, saturated to int32 */
		int32_t d_q8 = sat_s32(shr_round_s64((int64_t)config->kd_q16 * f[2] * derr_q5, D_SHIFT));
		out_q8 = (int32_t)clamp_s64((int64_t)p_q8 + pid->i_q8 + d_q8, 0, OUT_MAX_Q8);
	}
	if (factors_q12 != NULL) {
		factors_q12[0] = f[0];
		factors_q12[1] = f[1];
		factors_q12[2] = f[2];
	}
	return out_q8;
}
