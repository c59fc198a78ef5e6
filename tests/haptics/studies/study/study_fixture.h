#pragma once
// Shared by the study tests: a study file written from JSON, temporary folders, whole files.
#include <gtest/gtest.h>
#include <unistd.h>

#include <filesystem>
#include <fstream>
#include <nlohmann/json.hpp>
#include <string>

namespace palp::haptics::study_test {

namespace fs = std::filesystem;
using Json = nlohmann::json;

inline fs::path tempDir(const std::string& name) {
    const fs::path d =
        fs::temp_directory_path() / ("palp_study_" + name + "_" + std::to_string(::getpid()));
    fs::remove_all(d);
    fs::create_directories(d);
    return d;
}

inline std::string slurp(const fs::path& p) {
    std::ifstream in(p, std::ios::binary);
    return std::string((std::istreambuf_iterator<char>(in)), {});
}

inline void spit(const fs::path& p, const std::string& s) {
    std::ofstream out(p, std::ios::binary);
    out << s;
}

/// A small valid study: one lateral-sweep condition and one continuous-pressure condition, a
/// 1-up-2-down staircase of at most @p maxTrials trials.
inline Json smallStudy(int maxTrials = 40) {
    Json j = Json::parse(R"({
      "study": "small",
      "seed": 11,
      "reference_stiffness": 100,
      "procedure": {"method": "staircase", "start_level": 30, "step_sizes": [8, 4, 2],
                    "min_level": 0.5, "max_level": 80, "max_reversals": 0, "drop_first": 2},
      "fit": {"bootstrap": 50},
      "conditions": [
        {"name": "CP", "touch": "continuous-pressure"},
        {"name": "CL", "touch": "lateral-sweep", "profile": "tanh"}
      ]})");
    j["procedure"]["max_trials"] = maxTrials;
    return j;
}

}  // namespace palp::haptics::study_test
