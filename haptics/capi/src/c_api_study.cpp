// The C API's perception studies (palp/palp_study.h): a StudySession behind an opaque handle,
// each interval rendered on the host's device through a host session.
#include <cmath>
#include <limits>
#include <string>

#include "c_api_internal.h"
#include "palp/base/validate.h"
#include "palp/palp_study.h"
#include "palp/studies/study_session.h"

namespace ph = palp::haptics;
using namespace palp::capi;

struct palp_study {
    explicit palp_study(ph::StudySession s) : session(std::move(s)) {}
    ph::StudySession session;
};

namespace {

void copyName(const std::string& from, char (&to)[64]) noexcept {
    const std::size_t n = std::min(from.size(), sizeof to - 1);
    std::memcpy(to, from.data(), n);
    to[n] = '\0';
}

}  // namespace

extern "C" {

palp_status palp_study_open(const char* study_file, const char* log_file, int participant,
                            int resume, palp_study** out) {
    if (!study_file) return nullArgument("palp_study_open", "study_file");
    if (!log_file) return nullArgument("palp_study_open", "log_file");
    if (!out) return nullArgument("palp_study_open", "out");
    *out = nullptr;
    return guarded([&] {
        ph::StudySpec spec = ph::loadStudySpec(study_file);
        if (!resume && participant < 0)
            palp::throwExpected("palp_study_open: participant", "a number >= 0 for a new log",
                                std::to_string(participant));
        *out = new palp_study(
            resume ? ph::StudySession::resume(std::move(spec), log_file, participant)
                   : ph::StudySession::create(std::move(spec), log_file, participant));
        return PALP_OK;
    });
}

void palp_study_close(palp_study* study) { delete study; }

int palp_study_finished(const palp_study* study) {
    return study && study->session.finished() ? 1 : 0;
}

palp_status palp_study_next(const palp_study* study, palp_study_trial* out) {
    if (!study) return nullArgument("palp_study_next", "study");
    if (!out) return nullArgument("palp_study_next", "out");
    return guarded([&] {
        const ph::TrialPlan p = study->session.next();
        std::memset(out, 0, sizeof *out);
        out->trial = p.trial;
        out->condition = p.condition;
        out->condition_trial = p.conditionTrial;
        out->level_percent = p.levelPercent;
        out->comparison_interval = p.comparisonInterval;
        for (int i = 0; i < 2; ++i)
            out->interval_stiffness[i] =
                study->session.intervalParams(i + 1).coupling.baseStiffness;
        copyName(study->session.spec().conditions[static_cast<std::size_t>(p.condition)].name,
                 out->condition_name);
        return PALP_OK;
    });
}

palp_status palp_study_interval_session(palp_study* study, int interval,
                                        const palp_device_callbacks* device, palp_session** out) {
    if (!study) return nullArgument("palp_study_interval_session", "study");
    if (!device) return nullArgument("palp_study_interval_session", "device");
    if (!device->read_state)
        return nullArgument("palp_study_interval_session", "palp_device_callbacks.read_state");
    if (!out) return nullArgument("palp_study_interval_session", "out");
    *out = nullptr;
    return guarded([&] {
        const ph::SessionParams sp = study->session.intervalParams(interval);
        palp_session_params c;
        fromSession(sp, c);  // what palp_session_get_params reports (not the sigma ramp)
        *out = makeHostSession(study->session.scene(), sp, c, *device);
        return PALP_OK;
    });
}

palp_status palp_study_answer(palp_study* study, int response, double response_seconds,
                              const char* trace) {
    if (!study) return nullArgument("palp_study_answer", "study");
    return guarded([&] {
        ph::TrialAnswer a;
        a.response = response;
        a.responseSeconds = response_seconds;
        if (trace) {
            a.trace = trace;
            if (a.trace.find(',') != std::string::npos)
                palp::throwExpected("palp_study_answer: trace", "paths without ','",
                                    "'" + a.trace + "'");
        }
        (void)study->session.answer(a);
        return PALP_OK;
    });
}

palp_status palp_study_results(const palp_study* study, palp_study_result* out, int capacity,
                               int* count) {
    if (!study) return nullArgument("palp_study_results", "study");
    if (!count) return nullArgument("palp_study_results", "count");
    if (capacity > 0 && !out) return nullArgument("palp_study_results", "out");
    return guarded([&] {
        const auto results = study->session.results();
        *count = static_cast<int>(results.size());
        for (int i = 0; i < capacity && i < *count; ++i) {
            const ph::ConditionResult& r = results[static_cast<std::size_t>(i)];
            palp_study_result& o = out[i];
            std::memset(&o, 0, sizeof o);
            copyName(r.name, o.name);
            o.trials = r.trials;
            o.reversals = r.reversals;
            o.jnd_procedure_percent = r.procedureThreshold;
            o.jnd_fit_percent = r.fitThreshold;
            o.jnd_fit_lo = r.fitInterval.lo;
            o.jnd_fit_hi = r.fitInterval.hi;
        }
        return PALP_OK;
    });
}

}  // extern "C"
