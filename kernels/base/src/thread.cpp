#include "palp/base/thread.h"

#include <pthread.h>
#include <sched.h>

#include <cerrno>
#include <cstring>

namespace palp {

std::vector<int> allowedCpus() {
    std::vector<int> cpus;
    cpu_set_t set;
    CPU_ZERO(&set);
    if (sched_getaffinity(0, sizeof(set), &set) != 0) return cpus;
    for (std::size_t c = 0; c < CPU_SETSIZE; ++c)
        if (CPU_ISSET(c, &set)) cpus.push_back(static_cast<int>(c));
    return cpus;
}

std::string cpuListText(const std::vector<int>& cpus) {
    if (cpus.empty()) return "none";
    std::string text;
    for (std::size_t i = 0; i < cpus.size();) {
        std::size_t j = i;
        while (j + 1 < cpus.size() && cpus[j + 1] == cpus[j] + 1) ++j;
        if (!text.empty()) text += ',';
        text += std::to_string(cpus[i]);
        if (j > i) text += '-' + std::to_string(cpus[j]);
        i = j + 1;
    }
    return text;
}

int setCurrentThreadCpus(const std::vector<int>& cpus) noexcept {
    int highest = -1;
    for (int c : cpus) {
        if (c < 0) return EINVAL;
        if (c > highest) highest = c;
    }
    if (highest < 0) return EINVAL;
    const auto count = static_cast<std::size_t>(highest) + 1;
    cpu_set_t* set = CPU_ALLOC(count);
    if (!set) return ENOMEM;
    const std::size_t size = CPU_ALLOC_SIZE(count);
    CPU_ZERO_S(size, set);
    for (int c : cpus) CPU_SET_S(static_cast<std::size_t>(c), size, set);
    const int rc = pthread_setaffinity_np(pthread_self(), size, set);
    CPU_FREE(set);
    return rc;
}

int pinCurrentThread(int cpu) noexcept {
    if (cpu < 0) return EINVAL;
    try {
        return setCurrentThreadCpus({cpu});
    } catch (...) {  // the one-element list could not be allocated
        return ENOMEM;
    }
}

int setCurrentThreadFifo(int priority) noexcept {
    sched_param p{};
    p.sched_priority = priority;
    return pthread_setschedparam(pthread_self(), SCHED_FIFO, &p);
}

int nameCurrentThread(const char* name) noexcept {
    char cut[16] = {};
    std::strncpy(cut, name, sizeof cut - 1);
    return pthread_setname_np(pthread_self(), cut);
}

std::string errorText(int err) {
    char buf[256];
    // GNU strerror_r returns the message, which may or may not be in buf.
    const char* text = strerror_r(err, buf, sizeof buf);
    return text;
}

}  // namespace palp
