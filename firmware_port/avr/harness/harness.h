/*
 * harness.h: what the simulated board's main loop (main.c) and each law's glue file share.
 *
 * A glue file defines the globals the host reads and writes by their ELF symbols: law_in (the
 * step's input, first byte the operation), law_out (the step's output), law_state (the law's
 * state, what Marlin keeps per heater) and, for laws with settings, law_config. Its law_run()
 * does one operation. The call under test sits between MARK_ON() and MARK_OFF(), which raise and
 * clear PB0: the host notes the cycle counter at both edges, as a logic analyser would on a pin.
 */
#ifndef HARNESS_H
#define HARNESS_H

#include <avr/io.h>
#include <stdint.h>

#define OP_STEP 0  /* one call of the law on law_in */
#define OP_RESET 1 /* the law's reset (Marlin's pid_reset, a controller's reset()) */
#define OP_INIT 2  /* the state a power-up leaves (the Python port's constructor) */

#define MARK_ON() (PORTB = _BV(PORTB0))
#define MARK_OFF() (PORTB = 0)

/* A controller's law_in: a fresh reading and the target (Marlin's celsius_t). */
typedef struct {
	uint8_t op;
	int16_t temp_q5;  /* celsius_q5 */
	int16_t target_c; /* whole degC */
} reading_in_t;

void law_run(void);

#endif
