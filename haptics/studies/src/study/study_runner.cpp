// The 2IFC study runner: trial sequence, procedures, resume, responders and the analysis.
#include "palp/studies/study_runner.h"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <ctime>
#include <filesystem>
#include <map>
#include <variant>

#include "palp/base/error.h"
#include "palp/perception/observer.h"
#include "palp/perception/quest.h"
#include "palp/perception/staircase.h"
#include "palp/studies/study_stimuli.h"
#include "palp/studies/trace_csv.h"

namespace palp::haptics {

namespace {

std::uint64_t mix(std::uint64_t z) {
    z += 0x9e3779b97f4a7c15ull;
    z = (z ^ (z >> 30)) * 0xbf58476d1ce4e5b9ull;
    z = (z ^ (z >> 27)) * 0x94d049bb133111ebull;
    return z ^ (z >> 31);
}

/// A draw that depends only on where it is made in the study, never on earlier draws.
std::uint64_t draw(std::uint64_t seed, int participant, int condition, int trial,
                   std::uint64_t salt) {
    std::uint64_t h = mix(seed);
    for (std::uint64_t v :
         {static_cast<std::uint64_t>(participant), static_cast<std::uint64_t>(condition),
          static_cast<std::uint64_t>(trial), salt})
        h = mix(h ^ v);
    return h;
}

std::string nowUtc() {
    const std::time_t t = std::chrono::system_clock::to_time_t(std::chrono::system_clock::now());
    std::tm tm{};
    gmtime_r(&t, &tm);
    char buf[32];
    std::strftime(buf, sizeof buf, "%Y-%m-%dT%H:%M:%SZ", &tm);
    return buf;
}

bool sameLevel(double a, double b) { return std::abs(a - b) <= 1e-9 * std::max(1.0, std::abs(b)); }

}  // namespace

/// One condition's adaptive procedure.
struct StudyRunner::Procedure {
    explicit Procedure(const StudyProcedure& p) : spec(p) {
        if (p.method == StudyMethod::Quest) {
            state.emplace<perception::Quest>(p.quest);
        } else {
            state.emplace<perception::Staircase>(p.staircase);
        }
    }
    double level() const {
        if (const auto* s = std::get_if<perception::Staircase>(&state)) return s->level();
        const auto& q = std::get<perception::Quest>(state);
        return std::clamp(std::pow(10.0, q.next()), spec.minLevel, spec.maxLevel);
    }
    void update(double level, bool correct) {
        if (auto* s = std::get_if<perception::Staircase>(&state)) {
            s->update(correct);
        } else {
            std::get<perception::Quest>(state).update(std::log10(level), correct);
        }
        ++trials;
    }
    bool finished() const {
        if (const auto* s = std::get_if<perception::Staircase>(&state)) return s->finished();
        return std::get<perception::Quest>(state).finished();
    }
    StudyProcedure spec;
    std::variant<std::monostate, perception::Staircase, perception::Quest> state;
    int trials = 0;
};

StudyRunner::StudyRunner(StudySpec spec, int participant)
    : mSpec(std::move(spec)), mParticipant(participant) {
    if (participant < 0)
        throw ValueError("study runner: expected a participant >= 0, found " +
                         std::to_string(participant));
    mOrder = latinSquareRow(static_cast<int>(mSpec.conditions.size()), participant);
    for (std::size_t i = 0; i < mSpec.conditions.size(); ++i)
        mProcedures.push_back(std::make_unique<Procedure>(mSpec.procedure));
}

StudyRunner::~StudyRunner() = default;

int StudyRunner::current() const {
    for (int c : mOrder)
        if (!mProcedures[static_cast<std::size_t>(c)]->finished()) return c;
    return -1;
}

bool StudyRunner::finished() const { return current() < 0; }

TrialPlan StudyRunner::next() const {
    const int c = current();
    if (c < 0) throw ValueError("study " + mSpec.id + ": finished, no next trial");
    const Procedure& p = *mProcedures[static_cast<std::size_t>(c)];
    TrialPlan plan;
    plan.trial = mTrials;
    plan.condition = c;
    plan.conditionTrial = p.trials;
    plan.levelPercent = p.level();
    plan.comparisonInterval =
        1 + static_cast<int>(draw(mSpec.seed, mParticipant, c, p.trials, 1) >> 63);
    plan.observerSeed = draw(mSpec.seed, mParticipant, c, p.trials, 2);
    return plan;
}

TrialRecord StudyRunner::record(const TrialPlan& plan, const TrialAnswer& answer) {
    const TrialPlan want = next();
    if (plan.trial != want.trial || plan.condition != want.condition)
        throw ValueError("study " + mSpec.id + ": expected an answer to trial " +
                         std::to_string(want.trial) + ", found one to trial " +
                         std::to_string(plan.trial));
    if (answer.response != 1 && answer.response != 2)
        throw ValueError("study " + mSpec.id + ": expected a response 1 or 2, found " +
                         std::to_string(answer.response));
    TrialRecord r;
    r.trial = plan.trial;
    r.condition = plan.condition;
    r.conditionName = mSpec.conditions[static_cast<std::size_t>(plan.condition)].name;
    r.conditionTrial = plan.conditionTrial;
    r.levelPercent = plan.levelPercent;
    r.comparisonInterval = plan.comparisonInterval;
    r.referenceStiffnessNpm = mSpec.referenceStiffnessNpm;
    r.comparisonStiffnessNpm = mSpec.referenceStiffnessNpm * (1 + plan.levelPercent / 100);
    r.felt1 = answer.felt1;
    r.felt2 = answer.felt2;
    r.response = answer.response;
    r.correct = answer.response == plan.comparisonInterval;
    r.responseSeconds = answer.responseSeconds;
    r.timeUtc = nowUtc();
    r.trace = answer.trace;
    mProcedures[static_cast<std::size_t>(plan.condition)]->update(plan.levelPercent, r.correct);
    ++mTrials;
    return r;
}

void StudyRunner::replay(std::span<const TrialRecord> trials, const std::string& logName) {
    for (const TrialRecord& t : trials) {
        const auto fail = [&](const char* field, const std::string& want, const std::string& got) {
            throw ValueError(logName + ": trial " + std::to_string(t.trial) + ": " + field +
                             ": expected " + want + " (the study's sequence), found " + got +
                             "; the log is left as it was");
        };
        if (finished()) fail("trial", "none (the study is complete)", std::to_string(t.trial));
        const TrialPlan plan = next();
        const std::string& name = mSpec.conditions[static_cast<std::size_t>(plan.condition)].name;
        if (t.conditionName != name)
            fail("condition", "'" + name + "'", "'" + t.conditionName + "'");
        if (t.conditionTrial != plan.conditionTrial)
            fail("condition_trial", std::to_string(plan.conditionTrial),
                 std::to_string(t.conditionTrial));
        if (!sameLevel(t.levelPercent, plan.levelPercent))
            fail("level_percent", std::to_string(plan.levelPercent),
                 std::to_string(t.levelPercent));
        if (t.comparisonInterval != plan.comparisonInterval)
            fail("comparison_interval", std::to_string(plan.comparisonInterval),
                 std::to_string(t.comparisonInterval));
        TrialAnswer a;
        a.response = t.response;
        mProcedures[static_cast<std::size_t>(plan.condition)]->update(plan.levelPercent, t.correct);
        ++mTrials;
        (void)a;
    }
}

StudyLogHeader StudyRunner::logHeader() const {
    return {mSpec.id, mSpec.digest, mParticipant, mSpec.seed};
}

int runStudyTrials(StudyRunner& runner, const StudyResponder& responder, StudyLog& log,
                   int maxTrials) {
    int n = 0;
    while (!runner.finished() && (maxTrials < 0 || n < maxTrials)) {
        const TrialPlan plan = runner.next();
        const TrialAnswer answer = responder(runner.spec(), plan);
        if (answer.response == 0) break;
        log.append(runner.record(plan, answer));
        ++n;
    }
    return n;
}

StudyResponder simulatedResponder(std::shared_ptr<StudyStimuli> stimuli, std::string traceDir) {
    return [stimuli, traceDir](const StudySpec& spec, const TrialPlan& plan) {
        const StudyCondition& c = spec.conditions[static_cast<std::size_t>(plan.condition)];
        const bool compFirst = plan.comparisonInterval == 1;
        const double levels[2] = {compFirst ? plan.levelPercent : 0.0,
                                  compFirst ? 0.0 : plan.levelPercent};
        const IntervalFelt* felt[2] = {nullptr, nullptr};
        TrialAnswer a;
        for (int i = 0; i < 2; ++i) {
            std::vector<Snapshot> trace;
            felt[i] =
                &stimuli->feel(plan.condition, levels[i], traceDir.empty() ? nullptr : &trace);
            if (!traceDir.empty()) {
                char name[64];
                std::snprintf(name, sizeof name, "trial%05d-interval%d.csv", plan.trial, i + 1);
                const std::filesystem::path p = std::filesystem::path(traceDir) / name;
                writeTraceCsv(p, trace);
                a.trace += (i ? ";" : "") + p.string();
            }
        }
        a.felt1 = felt[0]->value(c.observer.felt);
        a.felt2 = felt[1]->value(c.observer.felt);
        int choice = 0;
        if (c.observer.kind == "gradient") {
            perception::GradientObserver o(c.observer.gradient, plan.observerSeed);
            choice = o.chooseGreater({felt[0]->profileM, felt[0]->profileNpm},
                                     {felt[1]->profileM, felt[1]->profileNpm});
        } else {
            perception::WeberObserver o(c.observer.weber, plan.observerSeed);
            choice = o.chooseGreater(a.felt1, a.felt2);
        }
        a.response = choice + 1;
        return a;
    };
}

std::vector<ConditionResult> analyseStudy(const StudySpec& spec,
                                          std::span<const TrialRecord> trials) {
    std::map<std::string, int> index;
    for (std::size_t i = 0; i < spec.conditions.size(); ++i)
        index[spec.conditions[i].name] = static_cast<int>(i);
    std::vector<std::vector<const TrialRecord*>> per(spec.conditions.size());
    for (const TrialRecord& t : trials) {
        const auto it = index.find(t.conditionName);
        if (it == index.end())
            throw ValueError("study log: trial " + std::to_string(t.trial) + ": condition '" +
                             t.conditionName + "' is not in study " + spec.id);
        per[static_cast<std::size_t>(it->second)].push_back(&t);
    }
    const double target = procedureTarget(spec.procedure);
    std::vector<ConditionResult> out;
    for (std::size_t c = 0; c < spec.conditions.size(); ++c) {
        ConditionResult r;
        r.name = spec.conditions[c].name;
        r.target = target;
        r.trials = static_cast<int>(per[c].size());
        std::map<double, perception::ResponseBlock> blocks;
        if (spec.procedure.method == StudyMethod::Staircase) {
            perception::Staircase s(spec.procedure.staircase);
            for (const TrialRecord* t : per[c])
                if (!s.finished()) s.update(t->correct);
            r.reversals = s.reversalCount();
            try {
                r.procedureThreshold =
                    s.threshold(spec.procedure.dropFirst, spec.procedure.useLast);
            } catch (const ValueError&) {
                r.note = std::to_string(r.reversals) + " reversals: too few after dropping " +
                         std::to_string(spec.procedure.dropFirst);
            }
        } else {
            perception::Quest q(spec.procedure.quest);
            for (const TrialRecord* t : per[c]) q.update(std::log10(t->levelPercent), t->correct);
            if (!per[c].empty()) r.procedureThreshold = std::pow(10.0, q.mean());
        }
        for (const TrialRecord* t : per[c]) {
            auto& b = blocks[t->levelPercent];
            b.level = t->levelPercent;
            b.trials += 1;
            b.correct += t->correct ? 1 : 0;
        }
        for (const auto& [level, b] : blocks) r.blocks.push_back(b);
        if (r.blocks.size() >= 2) {
            perception::FitOptions fo;
            fo.shape = spec.fit.shape;
            fo.gamma = 0.5;
            fo.lambdaMax = spec.fit.lambdaMax;
            try {
                r.fit = perception::fitPsychometric(r.blocks, fo);
                r.fitThreshold = perception::thresholdAt(r.fit->function, target);
                if (spec.fit.bootstrap > 0) {
                    perception::BootstrapOptions bo;
                    bo.samples = spec.fit.bootstrap;
                    bo.seed = spec.seed;
                    bo.coverage = spec.fit.coverage;
                    bo.thresholdLevels = {target};
                    perception::BootstrapResult br =
                        perception::bootstrapPsychometric(r.blocks, *r.fit, fo, bo);
                    r.fitInterval = br.thresholds.front();
                    r.bootstrapFits = std::move(br.fits);
                }
            } catch (const ValueError& e) {
                r.note += (r.note.empty() ? "" : "; ") + std::string("fit: ") + e.what();
            }
        } else {
            r.note += (r.note.empty() ? "" : "; ") + std::string("fit: fewer than two levels");
        }
        out.push_back(std::move(r));
    }
    return out;
}

}  // namespace palp::haptics
