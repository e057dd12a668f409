/*
 * adc.c: rounds of MIN_ADC_ISR_LOOPS = 10 ISRs (Marlin 2.1.x Marlin/src/module/temperature.cpp
 * Temperature::isr()): StartSampling, a Prepare/Measure pair per sensor, then padding. The
 * sample-and-hold captures the pin in Prepare, so the conversion is added there. Every
 * OVERSAMPLENR-th StartSampling hands the sums over (readings_ready), unless the main loop has not
 * taken the last ones: then they are dropped, as Marlin drops them. temp_count starts at 0, so
 * the first reading after reset sums 15 samples.
 */
#include "adc.h"

#define OVERSAMPLENR 16
#define MIN_ADC_ISR_LOOPS 10

void adc_init(adc_t *adc)
{
	adc->phase = 0;
	adc->temp_count = 0;
	adc->raw_ready = 0;
	for (uint8_t ch = 0; ch < ADC_CHANNELS; ch++) {
		adc->acc[ch] = 0;
		adc->raw[ch] = 0;
	}
}

static void readings_ready(adc_t *adc)
{
	for (uint8_t ch = 0; ch < ADC_CHANNELS; ch++) {
		if (!adc->raw_ready)
			adc->raw[ch] = adc->acc[ch];
		adc->acc[ch] = 0;
	}
	adc->raw_ready = 1;
}

void adc_isr(adc_t *adc, const uint16_t conversion[ADC_CHANNELS])
{
	uint8_t phase = adc->phase;
	if (phase == 0) {
		if (++adc->temp_count >= OVERSAMPLENR) {
			adc->temp_count = 0;
			readings_ready(adc);
		}
	} else if (phase < 2 * ADC_CHANNELS && (phase & 1)) {
		uint8_t ch = phase >> 1;
		adc->acc[ch] += conversion[ch];
	}
	adc->phase = phase + 1 < MIN_ADC_ISR_LOOPS ? phase + 1 : 0;
}
