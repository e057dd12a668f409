/* glue_bangbang_hotend.c: the hotend's bang-bang (bangbang.c), stateless, on the harness. */
#include "bangbang.h"
#include "harness.h"

reading_in_t law_in;

struct {
	uint8_t out;
} law_out;

void law_run(void)
{
	if (law_in.op != OP_STEP) {
		law_out.out = 0;
		return;
	}
	MARK_ON();
	law_out.out = bangbang_hotend(law_in.temp_q5, law_in.target_c);
	MARK_OFF();
}
