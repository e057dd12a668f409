/* glue_softpwm.c: the ISR's soft PWM (softpwm.c) on the harness. A step is one ISR, after the
 * main loop has written the amounts flagged in law_in.write (bit ch). */
#include "harness.h"
#include "softpwm.h"

struct {
	uint8_t op;
	uint8_t write;
	uint8_t amount[SOFTPWM_CHANNELS];
} law_in;

struct {
	uint8_t pins;
} law_out;

softpwm_t law_state;

void law_run(void)
{
	if (law_in.op != OP_STEP) {
		softpwm_init(&law_state);
		law_out.pins = 0;
		return;
	}
	for (uint8_t ch = 0; ch < SOFTPWM_CHANNELS; ch++)
		if (law_in.write & (1 << ch))
			law_state.amount[ch] = law_in.amount[ch];
	MARK_ON();
	law_out.pins = softpwm_isr(&law_state);
	MARK_OFF();
}
