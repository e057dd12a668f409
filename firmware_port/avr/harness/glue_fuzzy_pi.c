/* glue_fuzzy_pi.c: one heater's fuzzy-like PI (fuzzy_pi.c) on the harness. */
#include "fuzzy_pi.h"
#include "harness.h"

reading_in_t law_in;

struct {
	uint8_t out;
} law_out;

fuzzy_pi_state_t law_state;
fuzzy_pi_config_t law_config;

void law_run(void)
{
	switch (law_in.op) {
	case OP_INIT:
		fuzzy_pi_init(&law_state);
		law_out.out = 0;
		break;
	case OP_RESET:
		fuzzy_pi_reset(&law_state);
		law_out.out = 0;
		break;
	default:
		MARK_ON();
		law_out.out = fuzzy_pi_update(&law_state, &law_config, law_in.temp_q5, law_in.target_c);
		MARK_OFF();
	}
}
