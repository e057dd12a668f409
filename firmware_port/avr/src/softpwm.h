/*
 * softpwm.h: the heaters' software PWM in Marlin's temperature ISR, the C of
 * firmware_port/marlin/softpwm.py (SoftPwm.tick) for a hotend and a bed.
 */
#ifndef SOFTPWM_H
#define SOFTPWM_H

#include <stdint.h>

#define SOFTPWM_CHANNELS 2 /* hotend, bed */

/* The PWM state, 6 bytes. */
typedef struct {
	uint8_t pwm_count;                /* 0..127, starts at _BV(SOFT_PWM_SCALE) = 1 */
	uint8_t amount[SOFTPWM_CHANNELS]; /* 0..127, soft_pwm_amount written by the main loop */
	uint8_t count[SOFTPWM_CHANNELS];  /* the amount latched at the last wrap */
	uint8_t pins;                     /* bit ch: heater ch's output pin */
} softpwm_t;

void softpwm_init(softpwm_t *pwm);
/* One ISR: returns the pin levels (bit ch). */
uint8_t softpwm_isr(softpwm_t *pwm);

#endif
