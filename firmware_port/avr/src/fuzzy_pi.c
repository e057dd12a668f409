/*
 * fuzzy_pi.c: seed 004's Mamdani controller on the error and its change, as
 * firmware_port/fuzzy_pi.py FuzzyPi computes it. Both inputs are normalised onto an axis of
 * (n+1) * 4096 units (one set step br = 4096, so set k is centred at (k+1) * 4096 and the
 * triangles are shifts); at most two neighbouring sets fire per input, so at most three of the
 * 2n-1 output sets; the centroid is sampled at 8 points per output set step around the fired
 * sets; the crisp output is a change of duty, accumulated and clamped to 0..out_max.
 */
#include "fuzzy_pi.h"

#include "fixed.h"

#define BR_BITS 12 /* input axis: br = 4096 units; degrees Q12 */
#define MU_ONE ((int32_t)1 << BR_BITS)
#define GRID_BITS 3 /* output axis: 8 samples a set step */
#define GRID (1 << GRID_BITS)
#define CENTROID_BITS 9 /* centroid offset: Q9 grid units */
#define DUTY_BITS 16    /* duty: Q16.16 counts */

/* The sets that fire at one position: one, or two neighbours. */
typedef struct {
	uint8_t count;
	uint8_t set[2];
	uint16_t mu_q12[2];
} fired_t;

/* Degree of set k of n_sets at pos, in units of 1/br: a triangle of half-width br centred at
 * (k+1) * br; the outer two sets are trapezoids (eqs. 3-7). Serves both axes. */
static int32_t membership(int32_t pos, uint8_t k, uint8_t n_sets, int32_t br)
{
	int32_t centre = (int32_t)(k + 1) * br;
	int32_t distance = pos >= centre ? pos - centre : centre - pos;
	if ((k == 0 && pos <= centre) || (k == n_sets - 1 && pos >= centre))
		return br;
	return distance < br ? br - distance : 0;
}

/* Eq. (1) on the integer axis: value saturated to +-range, 0..(n+1) * 4096, zero in the middle.
 * value * half <= 32767 * 65536 < 2^31. */
static int32_t normalise(int32_t value_q5, int16_t range_q5, uint8_t n_sets)
{
	int32_t half = (int32_t)(n_sets + 1) << (BR_BITS - 1);
	value_q5 = clamp_s32(value_q5, -range_q5, range_q5);
	return half + div_round_s32(value_q5 * half, range_q5);
}

static void fuzzify(int32_t pos, uint8_t n_sets, fired_t *fired)
{
	int32_t left = (pos >> BR_BITS) - 1; /* the set centred at or left of pos, or -1 */
	if (left > n_sets - 1)
		left = n_sets - 1;
	fired->count = 0;
	for (int32_t k = left; k <= left + 1; k++) {
		if (k < 0 || k >= n_sets)
			continue;
		int32_t mu_q12 = membership(pos, (uint8_t)k, n_sets, MU_ONE);
		if (mu_q12 > 0) {
			fired->set[fired->count] = (uint8_t)k;
			fired->mu_q12[fired->count] = (uint16_t)mu_q12;
			fired->count++;
		}
	}
}

/* The change of duty (Q16.16 counts) for an error and its change: min-max inference over the
 * rules (i, j) -> output set i + j, sampled centroid about the midpoint of the fired sets. */
static int32_t change_q16(const fuzzy_pi_config_t *config, int32_t err_q5, int32_t derr_q5)
{
	uint8_t n = config->n_sets;
	fired_t e, de;
	fuzzify(normalise(err_q5, config->err_range_q5, n), n, &e);
	fuzzify(normalise(derr_q5, config->derr_range_q5, n), n, &de);
	uint8_t k_lo = e.set[0] + de.set[0];
	uint8_t k_hi = e.set[e.count - 1] + de.set[de.count - 1];
	uint16_t strength_q12[3] = {0, 0, 0};
	for (uint8_t i = 0; i < e.count; i++) {
		for (uint8_t j = 0; j < de.count; j++) {
			uint16_t mu = e.mu_q12[i] < de.mu_q12[j] ? e.mu_q12[i] : de.mu_q12[j];
			uint8_t slot = e.set[i] + de.set[j] - k_lo;
			if (mu > strength_q12[slot])
				strength_q12[slot] = mu;
		}
	}
	int16_t y_mid = (int16_t)(k_lo + k_hi + 2) << (GRID_BITS - 1);
	int32_t num = 0; /* sum of (y - y_mid) * degree, |num| <= 16 * den */
	int32_t den = 0; /* sum of degree, >= 6 * 4096 */
	for (int16_t y = (int16_t)k_lo << GRID_BITS; y <= (int16_t)(k_hi + 2) << GRID_BITS; y++) {
		uint16_t mu_q12 = 0;
		for (uint8_t k = k_lo; k <= k_hi; k++) {
			uint16_t shape = (uint16_t)membership(y, k, 2 * n - 1, GRID) << (BR_BITS - GRID_BITS);
			uint16_t clipped = strength_q12[k - k_lo] < shape ? strength_q12[k - k_lo] : shape;
			if (clipped > mu_q12)
				mu_q12 = clipped;
		}
		num += (int32_t)(y - y_mid) * mu_q12;
		den += mu_q12;
	}
	/* Q9 grid units from the zero output set's centre, |offset| <= 31 * 8 * 512 */
	int32_t offset_q9 = (int32_t)(y_mid - n * GRID) * (1 << CENTROID_BITS)
			    + div_round_s32(num * (1 << CENTROID_BITS), den);
	/* Q9 * Q4 / (n * 8) is Q16: 9 + 4 + 3 = 16 */
	return div_round_s32(offset_q9 * config->du_range_q4, n);
}

void fuzzy_pi_init(fuzzy_pi_state_t *pi)
{
	pi->err_prev_q5 = 0;
	fuzzy_pi_reset(pi);
}

void fuzzy_pi_reset(fuzzy_pi_state_t *pi)
{
	pi->duty_q16 = 0;
	pi->have_prev = 0;
}

uint8_t fuzzy_pi_update(fuzzy_pi_state_t *pi, const fuzzy_pi_config_t *config, int16_t temp_q5, int16_t target_c)
{
	if (target_c == 0) {
		fuzzy_pi_reset(pi);
		return 0;
	}
	int32_t err_q5 = (int32_t)target_c * TEMP_ONE - temp_q5;
	int32_t derr_q5 = pi->have_prev ? err_q5 - pi->err_prev_q5 : 0;
	pi->err_prev_q5 = err_q5;
	pi->have_prev = 1;
	int32_t duty_max_q16 = (int32_t)config->out_max << DUTY_BITS;
	pi->duty_q16 = clamp_s32(pi->duty_q16 + change_q16(config, err_q5, derr_q5), 0, duty_max_q16);
	return (uint8_t)shr_round_s32(pi->duty_q16, DUTY_BITS);
}
