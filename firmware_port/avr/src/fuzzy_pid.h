/*
 * fuzzy_pid.h: the fuzzy-PID of seed 001, the C of firmware_port/fuzzy_pid.py (FuzzyPid).
 */
#ifndef FUZZY_PID_H
#define FUZZY_PID_H

#include <stdint.h>

/* Settings and base gains, 22 bytes (FixedConstants in fuzzy_pid.py; RAM, since M301 sets the gains). */
typedef struct {
	uint32_t ke_q12;     /* Q12 per degC: e -> universe [-3, 3] */
	uint32_t kec_ps_q12; /* Q12 per degC per sample: Kec / PID_dT */
	uint8_t span_q4;     /* Q4: incremental reading, gains move by +-span */
	uint8_t literal;     /* 1: gain = base x centroid; 0: incremental */
	int32_t kp_q12;      /* as pid_gains_t */
	int32_t ki_q24;
	int32_t kd_q16;
} fuzzy_pid_config_t;

/* One heater's state, 7 bytes. */
typedef struct {
	int32_t i_q8;      /* Q8 counts, 0..255 * 256 */
	int16_t e_prev_q5; /* celsius_q5, saturated */
	uint8_t have_prev;
} fuzzy_pid_state_t;

void fuzzy_pid_reset(fuzzy_pid_state_t *pid);
/* One step; factors_q12 (kp, ki, kd gain factors, Q12) receives the terms as last computed,
 * like simple-pid's components, or is NULL. */
int32_t fuzzy_pid_update_q8(fuzzy_pid_state_t *pid, const fuzzy_pid_config_t *config, int16_t temp_q5,
			    int16_t target_c, int16_t *factors_q12);

#endif
