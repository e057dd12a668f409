/*
 * fuzzy_pi.h: the fuzzy-like PI of seed 004, the C of firmware_port/fuzzy_pi.py (FuzzyPi).
 */
#ifndef FUZZY_PI_H
#define FUZZY_PI_H

#include <stdint.h>

/* Settings, 8 bytes (a const struct, or RAM if G-code sets them). */
typedef struct {
	uint8_t n_sets;        /* sets per input, odd, 3..31 */
	int16_t err_range_q5;  /* celsius_q5: the error is normalised over +-range */
	int16_t derr_range_q5; /* celsius_q5 per sample: the change of error likewise */
	int16_t du_range_q4;   /* Q4 counts: the change of duty at the ends of the output axis */
	uint8_t out_max;       /* duty ceiling, counts of 0..255 */
} fuzzy_pi_config_t;

/* One heater's state, 9 bytes. */
typedef struct {
	int32_t duty_q16;    /* Q16.16 counts of 0..out_max */
	int32_t err_prev_q5; /* celsius_q5, the previous sample's error */
	uint8_t have_prev;   /* err_prev_q5 holds a sample since the last reset */
} fuzzy_pi_state_t;

void fuzzy_pi_init(fuzzy_pi_state_t *pi);
void fuzzy_pi_reset(fuzzy_pi_state_t *pi);
uint8_t fuzzy_pi_update(fuzzy_pi_state_t *pi, const fuzzy_pi_config_t *config, int16_t temp_q5, int16_t target_c);

#endif
