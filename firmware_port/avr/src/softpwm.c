/*
 * softpwm.c: SOFT_PWM_SCALE 0, no dither (Marlin 2.1.x Marlin/src/module/temperature.cpp
 * Temperature::isr() SoftPWM). A 7-bit counter runs 0..126 (one period = 127 ISRs); at the wrap
 * each channel latches its amount and goes high if it is non-zero; later it goes low once the
 * counter reaches the latched amount.
 */
#include "softpwm.h"

#define SOFT_PWM_PERIOD_TICKS 127

void softpwm_init(softpwm_t *pwm)
{
	pwm->pwm_count = 1;
	pwm->pins = 0;
	for (uint8_t ch = 0; ch < SOFTPWM_CHANNELS; ch++) {
		pwm->amount[ch] = 0;
		pwm->count[ch] = 0;
	}
}

uint8_t softpwm_isr(softpwm_t *pwm)
{
	uint8_t tmp = pwm->pwm_count;
	if (tmp >= SOFT_PWM_PERIOD_TICKS) {
		tmp -= SOFT_PWM_PERIOD_TICKS;
		for (uint8_t ch = 0; ch < SOFTPWM_CHANNELS; ch++) {
			pwm->count[ch] = pwm->amount[ch];
			if (pwm->amount[ch])
				pwm->pins |= (uint8_t)(1 << ch);
			else
				pwm->pins &= (uint8_t)~(1 << ch);
		}
	} else {
		for (uint8_t ch = 0; ch < SOFTPWM_CHANNELS; ch++)
			if (pwm->count[ch] <= tmp)
				pwm->pins &= (uint8_t)~(1 << ch);
	}
	pwm->pwm_count = tmp + 1;
	return pwm->pins;
}
