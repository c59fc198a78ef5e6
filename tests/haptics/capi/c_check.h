/* CHECK for the C API tests compiled as C11: a failed condition is printed with palp's last
 * error and counted in gFailures (main returns it); the test goes on. */
#ifndef PALP_TESTS_C_CHECK_H
#define PALP_TESTS_C_CHECK_H

#include <stdio.h>

#include "palp/palp.h"

static int gFailures = 0;

#define CHECK(cond)                                                                           \
    do {                                                                                      \
        if (!(cond)) {                                                                        \
            fprintf(stderr, "%s:%d: CHECK failed: %s (last error: %s)\n", __FILE__, __LINE__, \
                    #cond, palp_last_error());                                                \
            ++gFailures;                                                                      \
        }                                                                                     \
    } while (0)

#endif
