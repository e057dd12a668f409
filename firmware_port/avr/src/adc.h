/*
 * adc.h: the ADC part of Marlin's temperature ISR, the C of firmware_port/marlin/adc.py
 * (AdcSequencer.tick) for a hotend and a bed.
 */
#ifndef ADC_H
#define ADC_H

#include <stdint.h>

#define ADC_CHANNELS 2 /* hotend, bed */

/* The sequencer, 11 bytes. */
typedef struct {
	uint8_t phase;                /* 0..9, position in the round (0 = StartSampling) */
	uint8_t temp_count;           /* 0..15, rounds since the last reading */
	uint16_t acc[ADC_CHANNELS];   /* running sums, <= 16 * 1023 */
	uint16_t raw[ADC_CHANNELS];   /* the last completed sums */
	uint8_t raw_ready;            /* set on a reading, cleared by the main loop */
} adc_t;

void adc_init(adc_t *adc);
/* One ISR; conversion[ch] is what channel ch's pin converts to if this ISR samples it. */
void adc_isr(adc_t *adc, const uint16_t conversion[ADC_CHANNELS]);

#endif
