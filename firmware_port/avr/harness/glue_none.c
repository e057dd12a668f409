/* glue_none.c: no law. The empty board: its flash is the baseline each law's flash is measured
 * against, and its marked cycles (the marker's own write) are subtracted from each law's. */
#include "harness.h"

struct {
	uint8_t op;
} law_in;

void law_run(void)
{
	if (law_in.op != OP_STEP)
		return;
	MARK_ON();
	MARK_OFF();
}
