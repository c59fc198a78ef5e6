#pragma once
/// @file
/// A study run one trial at a time by a host that presents the two intervals itself: a person
/// palpating on a haptic device, the trial announced by a viewer and answered with its buttons
/// (the C API's palp_study, Python's palp.Study, `palp study --device-listen`).
///
/// The host asks for the next trial, builds a Session for each interval on its own device from
/// scene() and intervalParams() (the same phantom and coupling the simulated observer palpates),
/// lets the person touch each, and answers with the interval that felt stiffer; the answer is
/// logged and synced before the next trial, so the study can stop at any point and be resumed
/// from its log with the sequence an uninterrupted run would have given (study_runner.h).
/// @par Threading
/// One thread per StudySession; the Sessions a host builds from it are its own.

#include <filesystem>
#include <memory>
#include <vector>

#include "palp/haptics/scene.h"
#include "palp/haptics/session.h"
#include "palp/studies/study_runner.h"

namespace palp::haptics {

class StudySession {
  public:
    /// A new log at @p log for @p participant (>= 0); an existing file is refused
    /// (palp::IoError naming it) and left as it was.
    static StudySession create(StudySpec spec, const std::filesystem::path& log, int participant);
    /// Continues @p log. @p participant < 0 takes the log's own; another study, digest,
    /// participant or seed, or a row that is not the trial the study gives, is refused naming
    /// the log and the field, the log left as it was.
    static StudySession resume(StudySpec spec, const std::filesystem::path& log,
                               int participant = -1);
    StudySession(StudySession&&) noexcept;
    StudySession& operator=(StudySession&&) noexcept;
    ~StudySession();

    bool finished() const;
    /// The trial to present. @throw palp::ValueError once finished().
    TrialPlan next() const;
    /// The level of interval @p interval (1 or 2) of next(), percent: 0 for the reference.
    /// @throw palp::ValueError for another interval or once finished().
    double intervalLevel(int interval) const;
    /// The phantom next()'s condition is touched on (shared by both intervals).
    std::shared_ptr<const Scene> scene();
    /// Interval @p interval of next(): the coupling at its level, the study's friction, 1 kHz.
    /// The host sets its own servo (CPU, priority) and workspace fields.
    SessionParams intervalParams(int interval) const;
    /// Records @p answer to next(): response 1 or 2 (anything else is refused naming it; a host
    /// that stops simply stops asking), appended to the log and synced.
    /// @return the logged record.
    TrialRecord answer(const TrialAnswer& answer);

    /// Every trial logged so far, this run's and a resumed log's.
    const std::vector<TrialRecord>& trials() const;
    /// analyseStudy() of trials().
    std::vector<ConditionResult> results() const;
    const StudyRunner& runner() const;
    const StudySpec& spec() const;
    const std::filesystem::path& logPath() const;

  private:
    struct Impl;
    explicit StudySession(std::unique_ptr<Impl> impl);
    std::unique_ptr<Impl> mImpl;
};

}  // namespace palp::haptics
