// Every option of `palp palpate`, `palp convert`, `palp phantom` and `palp bench` given the
// values a hostile or careless user types: each numeric option nan, inf, -inf, -1, 0, 1e300 and
// an empty string, each text option an empty string. Each must be refused (exit 1, a message
// naming the option) or accepted where its range (shown in --help) says so, and then run to the
// end (exit 0); never an abort, never a hang (every run is bounded by `timeout`), never an
// output file left behind by a refusal.
//
// The options come from each command's --help, so an option added later is covered without
// touching this test.

#include <gtest/gtest.h>

#include <atomic>
#include <filesystem>
#include <functional>
#include <map>
#include <regex>
#include <set>
#include <sstream>
#include <string>
#include <thread>
#include <utility>
#include <vector>

#include "test_support.h"

namespace {

namespace fs = std::filesystem;
using palp::test::runCommand;

/// One option as --help lists it.
struct Option {
    std::string name;  ///< the long name, e.g. --k-base
    bool numeric = false;
    int arity = 1;  ///< values per occurrence (--centre takes 3)
};

/// The options of `palp <command> --help` that take a value.
std::vector<Option> optionsOf(const std::string& command) {
    const auto r = runCommand(palp::test::palpTool().string() + " " + command + " --help");
    EXPECT_EQ(r.exitCode, 0) << r.output;
    std::vector<Option> out;
    // "  --k-base FLOAT:a value in ..." / "  -o,--output TEXT REQUIRED" / "  --json   Print..."
    const std::regex line(R"(^\s+(?:-\w,)?(--[\w-]+)\s+(\S+)(.*)$)");
    std::istringstream in(r.output);
    for (std::string text; std::getline(in, text);) {
        std::smatch m;
        if (!std::regex_match(text, m, line)) continue;
        const std::string type = m[2];
        const bool takesValue = type.rfind("FLOAT", 0) == 0 || type.rfind("INT", 0) == 0 ||
                                type.rfind("UINT", 0) == 0 || type.rfind("TEXT", 0) == 0;
        if (!takesValue || m[1] == "--help") continue;
        Option o{m[1], type.rfind("TEXT", 0) != 0, 1};
        std::smatch count;
        const std::string rest = m[3];
        if (std::regex_search(rest, count, std::regex(R"( x (\d+))")))
            o.arity = std::stoi(count[1]);
        out.push_back(o);
    }
    return out;
}

/// A command line that runs quickly and writes @p outputs, with per-option prerequisites.
struct Base {
    std::string command;                                    ///< e.g. "palpate"
    std::vector<std::pair<std::string, std::string>> args;  ///< option -> value ("" for a flag)
    std::vector<std::string> outputs;                       ///< files the run writes
};

std::string commandLine(const Base& base, const Option& o, const std::string& value) {
    std::string line = "timeout 120 " + palp::test::palpTool().string() + " " + base.command;
    for (const auto& [name, v] : base.args) {
        if (name == o.name) continue;  // the option under test replaces the base's own
        line += " " + name;
        if (!v.empty()) line += " '" + v + "'";
    }
    std::string joined = value;
    for (int i = 1; i < o.arity; ++i) joined += "," + value;
    return line + " " + o.name + " '" + joined + "'";
}

/// One run of checkEveryOption: the command line and what it left.
struct Job {
    Option option;
    std::string value, line;
    std::vector<std::string> outputs;  ///< this run's own output paths
    palp::test::RunResult result;
    std::vector<std::string> leftBehind;  ///< outputs that exist after the run
};

/// Runs every bad value of every option of @p command on @p baseFor(option) and checks the
/// outcome; @p accepted lists the (option, value) pairs the option's range admits. The runs go
/// three at a time (each a process that mostly loads shared libraries), each writing into a
/// folder of its own so a refusal's check for files left behind sees only its own.
void checkEveryOption(const std::string& command, const std::function<Base(const Option&)>& baseFor,
                      const std::set<std::pair<std::string, std::string>>& accepted,
                      const std::set<std::string>& skip = {}) {
    const std::vector<Option> options = optionsOf(command);
    ASSERT_GT(options.size(), 3u) << command;
    const std::vector<std::string> numericValues = {"nan", "inf", "-inf", "-1", "0", "1e300", ""};
    palp::test::TempDir runs;
    std::vector<Job> jobs;
    for (const Option& o : options) {
        if (skip.count(o.name)) continue;
        const std::vector<std::string> values =
            o.numeric ? numericValues : std::vector<std::string>{""};
        for (const std::string& v : values) {
            Base base = baseFor(o);
            // The run's outputs move to a folder of its own (same file names).
            const fs::path dir = runs / std::to_string(jobs.size());
            fs::create_directories(dir);
            for (std::string& f : base.outputs) {
                const std::string moved = (dir / fs::path(f).filename()).string();
                for (auto& arg : base.args) {
                    if (arg.second == f) arg.second = moved;
                }
                f = moved;
            }
            jobs.push_back({o, v, commandLine(base, o, v), base.outputs, {}, {}});
        }
    }
    std::atomic<std::size_t> next{0};
    auto worker = [&] {
        for (;;) {
            const std::size_t i = next.fetch_add(1);
            if (i >= jobs.size()) return;
            Job& j = jobs[i];
            j.result = runCommand(j.line);
            for (const std::string& f : j.outputs) {
                if (fs::exists(f)) j.leftBehind.push_back(f);
            }
        }
    };
    std::vector<std::thread> pool;
    for (int t = 0; t < 3; ++t) pool.emplace_back(worker);
    for (std::thread& t : pool) t.join();
    int refused = 0, ran = 0;
    for (const Job& j : jobs) {
        const std::string& line = j.line;
        const auto& r = j.result;
        if (accepted.count({j.option.name, j.value}) > 0) {
            EXPECT_EQ(r.exitCode, 0) << line << "\n" << r.output;
            ++ran;
            continue;
        }
        ++refused;
        EXPECT_EQ(r.exitCode, 1) << "expected a refusal: " << line << "\n" << r.output;
        EXPECT_NE(r.output.find("palp: error: "), std::string::npos) << line << "\n" << r.output;
        EXPECT_NE(r.output.find(j.option.name), std::string::npos)
            << "the refusal must name " << j.option.name << ": " << line << "\n"
            << r.output;
        for (const std::string& f : j.leftBehind) {
            ADD_FAILURE() << f << " left behind by the refusal of: " << line;
        }
        // Numbers as the user wrote them (%g), not 1e300 spelled out in 301 digits.
        EXPECT_FALSE(std::regex_search(r.output, std::regex("[0-9]{40}"))) << line << "\n"
                                                                           << r.output;
    }
    std::printf("%s: %d refusals, %d accepted runs\n", command.c_str(), refused, ran);
}

std::set<std::pair<std::string, std::string>> accepts(
    const std::vector<std::pair<std::string, std::vector<std::string>>>& table) {
    std::set<std::pair<std::string, std::string>> out;
    for (const auto& [name, values] : table) {
        for (const auto& v : values) out.insert({name, v});
    }
    return out;
}

TEST(CliInputs, PalpateRefusesEveryBadNumberNamingTheOption) {
    palp::test::TempDir tmp;
    const std::string trace = (tmp / "t.csv").string(), map = (tmp / "m.png").string();
    const std::set<std::string> fem = {
        "--fem-cell-mm",  "--young-kpa", "--poisson",   "--fem-damping",   "--fem-beta",
        "--filter-mm",    "--bone-hu",   "--tissue-hu", "--fem-solver",    "--primary-nodes",
        "--secondary-hz", "--lod",       "--material",  "--material-table"};
    auto baseFor = [&](const Option& o) {
        std::string scene = "avc";
        if (o.name == "--shape") scene = "avcec";
        if (o.name == "--displacement" || fem.count(o.name)) scene = "bone";
        if (o.name == "--profile") scene = "stiffness";
        Base b{"palpate",
               {{"--phantom", scene},
                {"--voxel-mm", "2"},
                {"--fast", ""},
                {"--seconds", "0.05"},
                {"--trace", trace},
                {"--map", map}},
               {trace, map}};
        if (fem.count(o.name)) b.args.push_back({"--deformable", ""});
        if (o.name == "--primary-nodes" || o.name == "--secondary-hz" || o.name == "--lod")
            b.args.push_back({"--fem-solver", "regions"});
        if (o.name == "--radius" || o.name == "--frequency" || o.name == "--passes")
            b.args.push_back({"--trajectory", "circle"});
        if (o.name == "--hold") b.args.push_back({"--trajectory", "press"});
        if (o.name == "--sigma" || o.name == "--sigma-threshold" || o.name == "--tau-stop")
            b.args.push_back({"--source", "accumulate"});
        return b;
    };
    // What the ranges in --help admit among nan, inf, -inf, -1, 0, 1e300 and "".
    const auto ok = accepts({{"--quadrant", {"0"}},
                             {"--displacement", {"-1", "0"}},
                             {"--noise", {"0"}},
                             {"--seed", {"0"}},
                             {"--poisson", {"0"}},
                             {"--fem-damping", {"0"}},
                             {"--fem-beta", {"0"}},
                             {"--filter-mm", {"0"}},
                             {"--tissue-hu", {"-1", "0"}},
                             {"--threshold", {"-1", "0"}},
                             {"--sigma-threshold", {"-1", "0"}},
                             {"--ring", {"0"}},
                             {"--damping", {"0"}},
                             {"--surface-iso", {"-1", "0"}},
                             {"--mu-static", {"0"}},
                             {"--mu-dynamic", {"0"}},
                             {"--centre", {"-1", "0"}},
                             {"--hold", {"0"}},
                             {"--servo-cpu", {"-1", "0"}},
                             {"--servo-priority", {"0"}}});
    // --device, --press-axis and the like are text refused when empty; the phantom is the
    // base's own choice (testing it empty would also drop the scene the others need).
    checkEveryOption("palpate", baseFor, ok, {"--phantom"});
}

TEST(CliInputs, ConvertRefusesEveryBadNumberNamingTheOption) {
    palp::test::TempDir tmp;
    const std::string in = (tmp / "in.vdb").string(), out = (tmp / "out.vdb").string();
    const auto made =
        runCommand(palp::test::palpTool().string() + " phantom avc -o " + in + " --voxel-size 2");
    ASSERT_EQ(made.exitCode, 0) << made.output;
    auto baseFor = [&](const Option&) { return Base{"convert " + in, {{"-o", out}}, {out}}; };
    const auto ok = accepts({{"--background", {"-1", "0"}}, {"--volume", {"0"}}});
    checkEveryOption("convert", baseFor, ok, {"--output"});
}

TEST(CliInputs, PhantomRefusesEveryBadNumberNamingTheOption) {
    palp::test::TempDir tmp;
    const std::string out = (tmp / "p.vdb").string(), dicom = (tmp / "series").string();
    auto baseFor = [&](const Option& o) {
        std::string scene = "avc";
        if (o.name == "--shape") scene = "avcec";
        if (o.name == "--displacement" || o.name == "--bone-tilt") scene = "bone";
        if (o.name == "--width" || o.name == "--tanh-a" || o.name == "--hard-depth" ||
            o.name == "--profile")
            scene = "stiffness";
        const bool toDicom =
            o.name == "--slice-spacing" || o.name == "--slice-gaps" || o.name == "--tilt";
        Base b{"phantom " + scene, {{"--voxel-size", "4"}}, {out, dicom}};
        b.args.push_back(toDicom ? std::pair{std::string("--dicom-dir"), dicom}
                                 : std::pair{std::string("-o"), out});
        return b;
    };
    const auto ok = accepts({{"--quadrant", {"0"}},
                             {"--displacement", {"-1", "0"}},
                             {"--bone-tilt", {"-1", "0"}},
                             {"--hard-depth", {"0"}},
                             {"--fat", {"0"}},
                             {"--noise", {"0"}},
                             {"--blur", {"0"}},
                             {"--seed", {"0"}},
                             {"--margin", {"0"}},
                             {"--tilt", {"-1", "0"}}});
    checkEveryOption("phantom", baseFor, ok, {"--output", "--dicom-dir"});
}

TEST(CliInputs, BenchRefusesEveryBadNumberNamingTheOption) {
    // Accepted values run the real benchmarks, shortened.
    checkEveryOption(
        "bench servo",
        [](const Option&) {
            return Base{"bench servo", {{"--seconds", "0.05"}, {"--warm-up", "0"}}, {}};
        },
        accepts({{"--cpu", {"-1", "0"}},
                 {"--priority", {"0"}},
                 {"--spin-us", {"0"}},
                 {"--work-us", {"0"}},
                 {"--warm-up", {"0"}}}));
    checkEveryOption(
        "bench tick",
        [](const Option&) {
            return Base{"bench tick", {{"--ticks", "100"}, {"--voxel", "2"}}, {}};
        },
        accepts({{"--surface-iso", {"-1", "0"}}, {"--threshold", {"-1", "0"}}}));
    checkEveryOption(
        "bench rays",
        [](const Option&) {
            return Base{
                "bench rays", {{"--frames", "10"}, {"--warm-block", "0"}, {"--no-batch", ""}}, {}};
        },
        accepts({{"--threshold", {"-1", "0"}}, {"--warm-block", {"0"}}}));
}

}  // namespace
