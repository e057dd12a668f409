/* glue_thermistor.c: the table lookup (thermistor.c), stateless, on the harness. */
#include "harness.h"
#include "thermistor.h"

struct {
	uint8_t op;
	int16_t raw;
} law_in;

struct {
	int16_t temp_q5;
} law_out;

void law_run(void)
{
	if (law_in.op != OP_STEP) {
		law_out.temp_q5 = 0;
		return;
	}
	MARK_ON();
	law_out.temp_q5 = thermistor_lookup_q5(law_in.raw);
	MARK_OFF();
}
