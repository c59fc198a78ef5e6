// Placeholder: written in issue 4.
#include <gtest/gtest.h>
