#include "palp/base/thread.h"

#include <dirent.h>
#include <pthread.h>
#include <sched.h>
#include <unistd.h>

#include <cerrno>
#include <cstdlib>
#include <cstring>
#include <utility>

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

namespace {

/// Calls @p f(tid) for every thread of this process but the caller (none when /proc is absent).
template <class F>
void forOtherThreads(F&& f) noexcept {
    DIR* dir = opendir("/proc/self/task");
    if (!dir) return;
    const pid_t self = gettid();
    while (const dirent* entry = readdir(dir)) {
        char* end = nullptr;
        const long tid = std::strtol(entry->d_name, &end, 10);
        if (end == entry->d_name || *end != '\0' || tid <= 0 || tid == self) continue;
        f(static_cast<pid_t>(tid));
    }
    closedir(dir);
}

}  // namespace

CpuReservation::CpuReservation(CpuReservation&& other) noexcept
    : mCpu(std::exchange(other.mCpu, -1)), mMoved(std::move(other.mMoved)) {
    other.mMoved.clear();
}

CpuReservation& CpuReservation::operator=(CpuReservation&& other) noexcept {
    if (this != &other) {
        release();
        mCpu = std::exchange(other.mCpu, -1);
        mMoved = std::move(other.mMoved);
        other.mMoved.clear();
    }
    return *this;
}

CpuReservation CpuReservation::reserve(int cpu) {
    CpuReservation r;
    if (cpu < 0 || cpu >= CPU_SETSIZE) return r;
    r.mCpu = cpu;
    const auto index = static_cast<std::size_t>(cpu);
    // Twice: a thread started during the first pass by a thread not yet moved is caught by the
    // second (its parent's mask still held the CPU when it was created).
    for (int pass = 0; pass < 2; ++pass) {
        forOtherThreads([&](pid_t tid) {
            cpu_set_t before;
            CPU_ZERO(&before);
            if (sched_getaffinity(tid, sizeof before, &before) != 0) return;  // exited
            if (!CPU_ISSET(index, &before) || CPU_COUNT(&before) < 2) return;
            cpu_set_t after = before;
            CPU_CLR(index, &after);
            if (sched_setaffinity(tid, sizeof after, &after) != 0) return;
            r.mMoved.push_back({tid, before, after});
        });
    }
    return r;
}

void CpuReservation::release() noexcept {
    if (mMoved.empty()) {
        mCpu = -1;
        return;
    }
    forOtherThreads([&](pid_t tid) {
        cpu_set_t now;
        CPU_ZERO(&now);
        if (sched_getaffinity(tid, sizeof now, &now) != 0) return;
        // The thread itself if it was moved; else (started since) the first moved thread that
        // was left with the same mask: its parent's, most likely.
        const Moved* match = nullptr;
        for (const Moved& m : mMoved) {
            if (!CPU_EQUAL(&now, &m.after)) continue;
            if (m.tid == tid) {
                match = &m;
                break;
            }
            if (!match) match = &m;
        }
        if (match) sched_setaffinity(tid, sizeof match->before, &match->before);
    });
    // The calling thread too, if it was moved (release() from a thread other than the keeper).
    const pid_t self = gettid();
    for (const Moved& m : mMoved) {
        cpu_set_t now;
        CPU_ZERO(&now);
        if (m.tid == self && sched_getaffinity(0, sizeof now, &now) == 0 &&
            CPU_EQUAL(&now, &m.after))
            sched_setaffinity(0, sizeof m.before, &m.before);
    }
    mMoved.clear();
    mCpu = -1;
}

}  // namespace palp
