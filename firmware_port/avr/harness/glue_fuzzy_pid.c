/* glue_fuzzy_pid.c: one heater's fuzzy-PID (fuzzy_pid.c) on the harness; law_out also carries
 * the gain factors of the last step. */
#include <string.h>

#include "fuzzy_pid.h"
#include "harness.h"

reading_in_t law_in;

struct {
	int32_t out_q8;
	int16_t factors_q12[3];
} law_out;

fuzzy_pid_state_t law_state;
fuzzy_pid_config_t law_config;

void law_run(void)
{
	if (law_in.op != OP_STEP) {
		fuzzy_pid_reset(&law_state); /* power-up and reset() leave the same state */
		memset(&law_out, 0, sizeof law_out);
		return;
	}
	MARK_ON();
	law_out.out_q8 = fuzzy_pid_update_q8(&law_state, &law_config, law_in.temp_q5, law_in.target_c,
					     law_out.factors_q12);
	MARK_OFF();
}
