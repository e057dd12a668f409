/* glue_adc.c: the ISR's ADC sequencer (adc.c) on the harness. A step is one ISR, after the main
 * loop has taken the readings (cleared raw_ready) if law_in.take says so. */
#include "adc.h"
#include "harness.h"

struct {
	uint8_t op;
	uint8_t take;
	uint16_t conversion[ADC_CHANNELS];
} law_in;

adc_t law_state;

void law_run(void)
{
	if (law_in.op != OP_STEP) {
		adc_init(&law_state);
		return;
	}
	if (law_in.take)
		law_state.raw_ready = 0;
	MARK_ON();
	adc_isr(&law_state, law_in.conversion);
	MARK_OFF();
}
