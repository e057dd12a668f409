/*
 * pid.h: Marlin's PID law in fixed point, the C of firmware_port/marlin/pid.py (PidFixed).
 *
 * PID_PREV_TEMP_IN_BAND selects where the previous temperature for the derivative is updated:
 * 0 on every call (Marlin 2.0.x, the default), 1 only in band (Marlin 2.1.x).
 */
#ifndef PID_H
#define PID_H

#include <stdint.h>

#ifndef PID_PREV_TEMP_IN_BAND
#define PID_PREV_TEMP_IN_BAND 0
#endif

/* Gains as PidFixed.set_gains scales them (M301 time), 16 bytes. */
typedef struct {
	int32_t kp_q12;   /* Q.12, Kp */
	int32_t ki_q24;   /* Q.24, Ki * PID_dT */
	int32_t kd_q16;   /* Q.16, Kd / PID_dT */
	int32_t i_max_q5; /* the integral's ceiling, Q.5 degC x samples */
} pid_gains_t;

/* One heater's state, 11 bytes. */
typedef struct {
	int32_t i_sum_q5;      /* Q.5 degC x samples, 0..i_max_q5 */
	int32_t d_term_q8;     /* Q.8 counts, filtered derivative */
	int16_t prev_q5;       /* celsius_q5, previous temperature */
	uint8_t reset_pending; /* clear i and d on entering the band */
} pid_state_t;

void pid_init(pid_state_t *pid);
void pid_reset(pid_state_t *pid);
int32_t pid_update_q8(pid_state_t *pid, const pid_gains_t *gains, int16_t temp_q5, int16_t target_c);

#endif
