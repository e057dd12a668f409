/* glue_pid.c: one heater's PID (pid.c) on the harness. */
#include <string.h>

#include "harness.h"
#include "pid.h"

reading_in_t law_in;

struct {
	int32_t out_q8;
} law_out;

pid_state_t law_state;
pid_gains_t law_config;

void law_run(void)
{
	switch (law_in.op) {
	case OP_INIT:
		pid_init(&law_state);
		memset(&law_out, 0, sizeof law_out);
		break;
	case OP_RESET:
		pid_reset(&law_state);
		memset(&law_out, 0, sizeof law_out);
		break;
	default:
		MARK_ON();
		law_out.out_q8 = pid_update_q8(&law_state, &law_config, law_in.temp_q5, law_in.target_c);
		MARK_OFF();
	}
}
