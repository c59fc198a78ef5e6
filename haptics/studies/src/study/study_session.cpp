// A study run one trial at a time by a host that presents the intervals on its own device.
#include "palp/studies/study_session.h"

#include <cmath>
#include <optional>
#include <string>

#include "palp/base/error.h"
#include "palp/base/validate.h"
#include "palp/studies/study_stimuli.h"

namespace palp::haptics {

struct StudySession::Impl {
    explicit Impl(StudySpec s, int participant)
        : spec(std::move(s)), runner(spec, participant), stimuli(spec) {}
    StudySpec spec;
    StudyRunner runner;
    StudyStimuli stimuli;
    std::optional<StudyLog> log;
    std::vector<TrialRecord> trials;

    void requireTrial(const char* what) const {
        if (runner.finished())
            throw ValueError(std::string("study ") + spec.id + ": " + what +
                             ": expected a trial to present, found the study finished");
    }
    double level(int interval) const {
        requireTrial("interval level");
        if (interval != 1 && interval != 2)
            throwExpected("study interval", "1 or 2", std::to_string(interval));
        const TrialPlan p = runner.next();
        return p.comparisonInterval == interval ? p.levelPercent : 0.0;
    }
};

StudySession::StudySession(std::unique_ptr<Impl> impl) : mImpl(std::move(impl)) {}
StudySession::StudySession(StudySession&&) noexcept = default;
StudySession& StudySession::operator=(StudySession&&) noexcept = default;
StudySession::~StudySession() = default;

StudySession StudySession::create(StudySpec spec, const std::filesystem::path& log,
                                  int participant) {
    auto impl = std::make_unique<Impl>(std::move(spec), participant);
    impl->log.emplace(StudyLog::create(log, impl->runner.logHeader()));
    return StudySession(std::move(impl));
}

StudySession StudySession::resume(StudySpec spec, const std::filesystem::path& log,
                                  int participant) {
    if (participant < 0) {
        StudyLogHeader h;
        (void)readStudyLog(log, h);
        participant = h.participant;
    }
    auto impl = std::make_unique<Impl>(std::move(spec), participant);
    impl->log.emplace(StudyLog::resume(log, impl->runner.logHeader(), impl->trials));
    impl->runner.replay(impl->trials, log.string());
    return StudySession(std::move(impl));
}

bool StudySession::finished() const { return mImpl->runner.finished(); }

TrialPlan StudySession::next() const { return mImpl->runner.next(); }

double StudySession::intervalLevel(int interval) const { return mImpl->level(interval); }

std::shared_ptr<const Scene> StudySession::scene() {
    mImpl->requireTrial("scene");
    return mImpl->stimuli.sceneFor(mImpl->runner.next().condition);
}

SessionParams StudySession::intervalParams(int interval) const {
    const double level = mImpl->level(interval);
    return mImpl->stimuli.sessionParams(mImpl->runner.next().condition, level);
}

TrialRecord StudySession::answer(const TrialAnswer& answer) {
    mImpl->requireTrial("answer");
    if (answer.response != 1 && answer.response != 2)
        throwExpected("study answer response", "1 or 2 (the interval that felt stiffer)",
                      std::to_string(answer.response));
    if (!(answer.responseSeconds >= 0) || !std::isfinite(answer.responseSeconds))
        throwExpected("study answer responseSeconds", "a finite time >= 0 s",
                      std::to_string(answer.responseSeconds));
    const TrialPlan plan = mImpl->runner.next();
    TrialRecord r = mImpl->runner.record(plan, answer);
    mImpl->log->append(r);
    mImpl->trials.push_back(r);
    return r;
}

const std::vector<TrialRecord>& StudySession::trials() const { return mImpl->trials; }

std::vector<ConditionResult> StudySession::results() const {
    return analyseStudy(mImpl->spec, mImpl->trials);
}

const StudyRunner& StudySession::runner() const { return mImpl->runner; }
const StudySpec& StudySession::spec() const { return mImpl->spec; }
const std::filesystem::path& StudySession::logPath() const { return mImpl->log->path(); }

}  // namespace palp::haptics
