/*
 * pid.c: Marlin 2.1's PID_t::get_pid_output (Marlin/src/module/temperature.h) in fixed point, as
 * firmware_port/marlin/pid.py PidFixed.update_q8 computes it: bang-bang outside +-10 degC, a
 * one-sided sum of errors clamped at i_max, derivative on measurement through the
 * d += (d_in - d) / 20 filter (1 - PID_K1), output 0..255 in Q.8. Bounds of every intermediate
 * are in pid.py and checked there by tests/test_pid_properties.py.
 */
#include "pid.h"

#include "fixed.h"

#define OUT_FRAC_BITS 8
#define P_SHIFT (12 + TEMP_FRAC_BITS - OUT_FRAC_BITS) /* Q.17 product -> Q.8 */
#define I_SHIFT (24 + TEMP_FRAC_BITS - OUT_FRAC_BITS) /* Q.29 product -> Q.8 */
#define D_SHIFT (16 + TEMP_FRAC_BITS - OUT_FRAC_BITS) /* Q.21 product -> Q.8 */
#define FUNCTIONAL_RANGE_Q5 ((int32_t)10 * TEMP_ONE)  /* PID_FUNCTIONAL_RANGE 10 degC */
#define OUT_MAX_Q8 ((int32_t)255 << OUT_FRAC_BITS)    /* PID_MAX */
#define D_RAW_LIMIT_Q8 ((int64_t)1 << (21 + OUT_FRAC_BITS))
#define D_FILTER_DIVISOR 20 /* 1 / (1 - PID_K1), PID_K1 = 0.95 */

void pid_init(pid_state_t *pid)
{
	pid->prev_q5 = 0; /* Marlin starts temp_dState at 0 */
	pid_reset(pid);
}

void pid_reset(pid_state_t *pid)
{
	pid->i_sum_q5 = 0;
	pid->d_term_q8 = 0;
	pid->reset_pending = 1;
}

int32_t pid_update_q8(pid_state_t *pid, const pid_gains_t *gains, int16_t temp_q5, int16_t target_c)
{
	int32_t e_q5 = (int32_t)target_c * TEMP_ONE - temp_q5;
	int32_t out_q8;
	if (target_c == 0 || e_q5 < -FUNCTIONAL_RANGE_Q5) {
		out_q8 = 0;
		pid->reset_pending = 1;
	} else if (e_q5 > FUNCTIONAL_RANGE_Q5) {
		out_q8 = OUT_MAX_Q8;
		pid->reset_pending = 1;
	} else {
		if (pid->reset_pending) {
			pid->reset_pending = 0;
			pid->i_sum_q5 = 0;
			pid->d_term_q8 = 0;
		}
		pid->i_sum_q5 = clamp_s32(pid->i_sum_q5 + e_q5, 0, gains->i_max_q5);
		/* kp_q12 * e_q5 < 2^22 * 320: an int32 product */
		int32_t p_q8 = shr_round_s32(gains->kp_q12 * e_q5, P_SHIFT);
		/* ki_q24 * i_sum_q5 <= 255 * 2^29: int64 (long long), back to int32 */
		int32_t i_q8 = (int32_t)shr_round_s64((int64_t)gains->ki_q24 * pid->i_sum_q5, I_SHIFT);
		/* kd_q16 * dT in int64, saturated to +-2^29 before it returns to int32 */
		int64_t d_in = shr_round_s64((int64_t)gains->kd_q16 * ((int32_t)pid->prev_q5 - temp_q5), D_SHIFT);
		int32_t d_in_q8 = (int32_t)clamp_s64(d_in, -D_RAW_LIMIT_Q8, D_RAW_LIMIT_Q8);
		pid->d_term_q8 += div_round_s32(d_in_q8 - pid->d_term_q8, D_FILTER_DIVISOR);
		out_q8 = clamp_s32(p_q8 + i_q8 + pid->d_term_q8, 0, OUT_MAX_Q8);
#if PID_PREV_TEMP_IN_BAND
		pid->prev_q5 = temp_q5;
#endif
	}
#if !PID_PREV_TEMP_IN_BAND
	pid->prev_q5 = temp_q5;
#endif
	return out_q8;
}
