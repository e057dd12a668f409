/*
 * main.c: the simulated board's main loop. It waits for the host's command in the mailbox, runs
 * one operation of the law (law_run, from the law's glue file) and writes the mailbox back to
 * idle. No interrupts: the host is the only clock.
 *
 * The mailbox lives in .bss, which crt0 clears after reset, so the host waits for main() to write
 * MAILBOX_IDLE before it writes anything (simavr's reset leaves SRAM at 0, never MAILBOX_IDLE).
 * Before that, main() paints the free SRAM between the end of .bss and its own stack with
 * STACK_PAINT, so the host can find the deepest byte any call wrote: the peak stack.
 */
#include "harness.h"

#define MAILBOX_IDLE 0xA5
#define MAILBOX_RUN 0x01
#define STACK_PAINT 0x5A
#define STACK_MARGIN 2 /* bytes below paint_stack()'s frame left unpainted */

volatile uint8_t mailbox;
extern uint8_t __bss_end;

static void paint_stack(void)
{
	uint8_t *p = &__bss_end;
	uint8_t *top = (uint8_t *)SP - STACK_MARGIN;
	while (p < top)
		*p++ = STACK_PAINT;
}

int main(void)
{
	paint_stack();
	DDRB = _BV(DDB0);
	mailbox = MAILBOX_IDLE;
	for (;;) {
		while (mailbox != MAILBOX_RUN) {
		}
		law_run();
		mailbox = MAILBOX_IDLE;
	}
}
