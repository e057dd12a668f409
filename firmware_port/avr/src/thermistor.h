/*
 * thermistor.h: the firmware's thermistor table and its lookup, the C of
 * firmware_port/thermistor.py (TempTable.lookup_q5) on the B3950 table (Marlin's type 11 part).
 */
#ifndef THERMISTOR_H
#define THERMISTOR_H

#include <stdint.h>

/* A row, 4 bytes: Marlin's temp_entry_t {raw_t value; celsius_t celsius;}, here celsius in Q10.5. */
typedef struct {
	int16_t raw;     /* sum of OVERSAMPLENR 10-bit samples, ascending */
	int16_t temp_q5; /* celsius_q5, descending */
} temp_entry_t;

int16_t thermistor_lookup_q5(int16_t raw);

#endif
