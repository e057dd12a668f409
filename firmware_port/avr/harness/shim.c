/*
 * shim.c: the host side of the AVR harness, a small C library on libsimavr that Python drives
 * through ctypes (firmware_port/avr/sim.py).
 *
 * libsimavr has no accessors for its simulator state and its avr_t layout changes between
 * versions, so this file, compiled against the installed headers, is the only code that touches
 * avr_t. It loads an ELF, exposes the data space, and runs the firmware one step at a time: copy
 * the step's input into SRAM, write the mailbox command, run instructions until the firmware
 * writes the mailbox back to idle, copy the output regions out. Stepping stays in C, so a
 * sequence of steps costs one call from Python.
 *
 * Cycles per call: the firmware raises a marker bit in PORTB just before the call under test and
 * clears it just after (harness.h); the shim notes simavr's cycle counter at both edges.
 */
#include <fcntl.h>
#include <stdarg.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

#include "sim_avr.h"
#include "sim_elf.h"

#define SHIM_TIMEOUT (-1)
#define SHIM_CRASHED (-2)
#define SHIM_BAD_ADDRESS (-3)

static void quiet_logger(avr_t *avr, const int level, const char *format, va_list ap)
{
	(void)avr;
	(void)level;
	(void)format;
	(void)ap;
}

/* libsimavr prints banners on stdout ("Starting atmega328p ...", "Loaded N .text"): run fn
 * with fd 1 on /dev/null, flushing C's buffer before it is pointed back. */
static int saved_stdout = -1;

static void stdout_off(void)
{
	int null_fd = open("/dev/null", O_WRONLY);
	fflush(stdout);
	saved_stdout = dup(1);
	if (null_fd >= 0) {
		dup2(null_fd, 1);
		close(null_fd);
	}
}

static void stdout_on(void)
{
	fflush(stdout);
	if (saved_stdout >= 0) {
		dup2(saved_stdout, 1);
		close(saved_stdout);
		saved_stdout = -1;
	}
}

/* A simulated MCU running the ELF at path, or NULL if the ELF or the MCU cannot be loaded. */
avr_t *shim_open(const char *path, const char *mcu, uint32_t frequency_hz)
{
	elf_firmware_t *firmware = calloc(1, sizeof(elf_firmware_t));
	avr_t *avr = NULL;
	if (!firmware)
		return NULL;
	avr_global_logger_set(quiet_logger);
	stdout_off();
	if (elf_read_firmware(path, firmware) == 0) {
		avr = avr_make_mcu_by_name(mcu);
		if (avr) {
			avr_init(avr);
			avr->log = 0;
			avr_load_firmware(avr, firmware);
			avr->frequency = frequency_hz;
		}
	}
	stdout_on();
	free(firmware->flash);
	free(firmware->eeprom);
	free(firmware);
	return avr;
}

void shim_close(avr_t *avr)
{
	if (!avr)
		return;
	avr_terminate(avr);
	free(avr);
}

uint8_t *shim_data(avr_t *avr)
{
	return avr->data;
}

uint32_t shim_ramend(avr_t *avr)
{
	return avr->ramend;
}

/* Run until data[addr] == value. 0, or SHIM_TIMEOUT after max_cycles, or SHIM_CRASHED. While
 * running, the cycles between the marker's rise and fall go to *marked (0 if it did not rise). */
static int run_until(avr_t *avr, uint16_t addr, uint8_t value, uint16_t mark_addr, uint8_t mark_mask,
		     uint64_t max_cycles, uint32_t *marked)
{
	uint64_t end = avr->cycle + max_cycles;
	uint64_t rise = 0;
	uint8_t high = 0;
	*marked = 0;
	while (avr->data[addr] != value) {
		int state = avr_run(avr);
		if (state == cpu_Done || state == cpu_Crashed || state == cpu_Stopped)
			return SHIM_CRASHED;
		if (mark_mask) {
			uint8_t level = avr->data[mark_addr] & mark_mask;
			if (level && !high)
				rise = avr->cycle;
			else if (!level && high)
				*marked = (uint32_t)(avr->cycle - rise);
			high = level;
		}
		if (avr->cycle > end)
			return SHIM_TIMEOUT;
	}
	return 0;
}

/* Boot: run until the firmware's main() writes the idle value to the mailbox. */
int shim_wait(avr_t *avr, uint16_t mailbox, uint8_t idle, uint64_t max_cycles)
{
	uint32_t unused;
	if (mailbox > avr->ramend)
		return SHIM_BAD_ADDRESS;
	return run_until(avr, mailbox, idle, 0, 0, max_cycles, &unused);
}

/*
 * n_steps steps. Step i: copy in_size bytes from in + i * in_size to data[in_addr], write
 * command to data[mailbox], run until the firmware writes idle back, then append each region
 * (addr, size pairs in regions) to out, and the marked cycles to cycles[i]. Returns the number
 * of steps done, or a negative SHIM_ code.
 */
int32_t shim_steps(avr_t *avr, uint16_t mailbox, uint8_t command, uint8_t idle, uint16_t in_addr, uint16_t in_size,
		   const uint8_t *in, uint32_t n_steps, const uint16_t *regions, uint8_t n_regions, uint8_t *out,
		   uint16_t mark_addr, uint8_t mark_mask, uint32_t *cycles, uint64_t max_cycles_per_step)
{
	if (mailbox > avr->ramend || mark_addr > avr->ramend || (uint32_t)in_addr + in_size > avr->ramend + 1u)
		return SHIM_BAD_ADDRESS;
	for (uint8_t r = 0; r < n_regions; r++)
		if ((uint32_t)regions[2 * r] + regions[2 * r + 1] > avr->ramend + 1u)
			return SHIM_BAD_ADDRESS;
	for (uint32_t i = 0; i < n_steps; i++) {
		memcpy(avr->data + in_addr, in + (size_t)i * in_size, in_size);
		avr->data[mailbox] = command;
		int status = run_until(avr, mailbox, idle, mark_addr, mark_mask, max_cycles_per_step, &cycles[i]);
		if (status < 0)
			return status;
		for (uint8_t r = 0; r < n_regions; r++) {
			memcpy(out, avr->data + regions[2 * r], regions[2 * r + 1]);
			out += regions[2 * r + 1];
		}
	}
	return (int32_t)n_steps;
}
