/*
 * The platform functions of the worked main loop of docs/rul-on-the-device.md section 6, on a
 * PC: acquisitions from a text file (t, then the CIs, per line), non-volatile memory in a
 * static buffer, alerts printed. main() runs the loop, cuts the power after argv[2]
 * acquisitions, runs it again (it restores the state from the saved bytes) and prints the
 * number of acquisitions the restored state holds at the end.
 */
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <stdint.h>

#include "bearing.h"

int monitor(void);

static FILE *acq;
static uint8_t nvm[BEARING_STATE_BYTES];
static int nvm_written = 0;
static int power_cut_after = -1;
static int seen = 0;

int platform_next_acquisition(bearing_time *t, bearing_real ci[BEARING_N_CI])
{
    double v;
    int i;

    if (seen == power_cut_after) {
        power_cut_after = -1;
        return 1;
    }
    if (fscanf(acq, "%lf", &v) != 1) {
        return 1;
    }
    *t = v;
    for (i = 0; i < BEARING_N_CI; i++) {
        if (fscanf(acq, "%lf", &v) != 1) {
            return 1;
        }
        ci[i] = v;
    }
    seen++;
    return 0;
}

int platform_nvm_read(uint8_t *buf, uint32_t size)
{
    if (!nvm_written || size != sizeof nvm) {
        return 1;
    }
    memcpy(buf, nvm, size);
    return 0;
}

int platform_nvm_write(const uint8_t *buf, uint32_t size)
{
    memcpy(nvm, buf, size);
    nvm_written = 1;
    return 0;
}

void platform_alert(uint8_t level, bearing_real rul_low, bearing_real rul_high)
{
    printf("alert %d %.17g %.17g\n", level, (double)rul_low, (double)rul_high);
}

int main(int argc, char **argv)
{
    bearing_state s;

    if (argc != 3 || !(acq = fopen(argv[1], "r"))) {
        return 2;
    }
    power_cut_after = atoi(argv[2]);
    if (monitor() != 0 || monitor() != 0) {
        return 3;
    }
    if (bearing_restore(&s, nvm, sizeof nvm) != BEARING_OK) {
        return 4;
    }
    printf("n %u\n", (unsigned)s.n);
    return 0;
}
