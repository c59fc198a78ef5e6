#pragma once
/// @file
/// A study's trial log: CSV, one row per trial, append-only, with a header naming the study,
/// its digest, the participant and the seed, so that a log refits on its own (every level,
/// interval order and response is in it) and is never resumed under another study.
///
///     # palp study log 1
///     # study touch-modes
///     # digest 5f0c...
///     # participant 3
///     # seed 7
///     study,participant,trial,condition,condition_trial,level_percent,comparison_interval,
///     reference_stiffness_npm,comparison_stiffness_npm,felt_1,felt_2,response,correct,
///     response_seconds,time_utc,trace
///
/// Each row is written whole and flushed to the disk (fsync) before the next trial, so an
/// interruption loses at most the trial being answered.

#include <cstdint>
#include <cstdio>
#include <filesystem>
#include <string>
#include <vector>

namespace palp::haptics {

/// One trial as logged.
struct TrialRecord {
    int trial = 0;      ///< 0-based over the whole study
    int condition = 0;  ///< index into StudySpec::conditions
    std::string conditionName;
    int conditionTrial = 0;  ///< 0-based within the condition
    double levelPercent = 0;
    int comparisonInterval = 1;        ///< 1 or 2
    double referenceStiffnessNpm = 0;  ///< k_s of the reference interval
    double comparisonStiffnessNpm = 0;
    /// What the simulated hand felt in intervals 1 and 2 (the observer's quantity; NaN when a
    /// person answered).
    double felt1 = 0, felt2 = 0;
    int response = 1;  ///< the interval named stiffer, 1 or 2
    bool correct = false;
    double responseSeconds = 0;  ///< from the question to the answer (0 for a simulation)
    std::string timeUtc;         ///< when the answer came, ISO 8601
    std::string trace;           ///< the intervals' trace files ("a.csv;b.csv"), or empty
};

struct StudyLogHeader {
    std::string study;
    std::string digest;
    int participant = 0;
    std::uint64_t seed = 0;
};

/// An open log that trials are appended to.
/// @par Threading
/// One thread.
class StudyLog {
  public:
    /// Creates @p path with @p header; refuses (palp::IoError naming it) an existing file, so
    /// no log is ever overwritten.
    static StudyLog create(const std::filesystem::path& path, const StudyLogHeader& header);
    /// Opens @p path to append after its trials (read into @p trials). Refuses, naming the file
    /// and the header field, a log of another study, digest (the study file changed),
    /// participant or seed than @p expected, and a log whose last row is cut short; the file is
    /// left as it was.
    static StudyLog resume(const std::filesystem::path& path, const StudyLogHeader& expected,
                           std::vector<TrialRecord>& trials);
    StudyLog(StudyLog&& other) noexcept;
    StudyLog& operator=(StudyLog&&) = delete;
    StudyLog(const StudyLog&) = delete;
    ~StudyLog();

    /// Appends @p record, flushed and synced. @throw palp::IoError naming the file.
    void append(const TrialRecord& record);
    const std::filesystem::path& path() const { return mPath; }

  private:
    StudyLog(std::filesystem::path path, std::FILE* file, StudyLogHeader header);
    std::filesystem::path mPath;
    std::FILE* mFile = nullptr;
    StudyLogHeader mHeader;
};

/// Reads a log: its header into @p header and its rows.
/// @throw palp::IoError when unreadable; palp::FormatError naming the file, line and column.
std::vector<TrialRecord> readStudyLog(const std::filesystem::path& path, StudyLogHeader& header);

/// The column line of a log.
const char* studyLogColumns() noexcept;

}  // namespace palp::haptics
