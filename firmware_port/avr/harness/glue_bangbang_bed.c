/* glue_bangbang_bed.c: the bed's bang-bang (bangbang.c) on the harness. */
#include "bangbang.h"
#include "harness.h"

reading_in_t law_in;

struct {
	uint8_t out;
} law_out;

bangbang_bed_t law_state;

void law_run(void)
{
	if (law_in.op != OP_STEP) {
		bangbang_bed_reset(&law_state); /* power-up and reset() both start from off */
		law_out.out = 0;
		return;
	}
	MARK_ON();
	law_out.out = bangbang_bed(&law_state, law_in.temp_q5, law_in.target_c);
	MARK_OFF();
}
