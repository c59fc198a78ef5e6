#include "palp/volume/find_scans.h"

#include <algorithm>
#include <map>
#include <set>
#include <utility>

#include "dicom_plugin.h"
#include "palp/base/error.h"

namespace palp::volume {

namespace fs = std::filesystem;

namespace {

/// The deepest folder holding every one of @p files.
fs::path commonFolder(const std::vector<fs::path>& files) {
    fs::path common = files.front().parent_path();
    for (const fs::path& f : files) {
        const fs::path dir = f.parent_path();
        while (!common.empty()) {
            const auto [c, d] = std::mismatch(common.begin(), common.end(), dir.begin(), dir.end());
            if (c == common.end()) break;  // common is dir or one of its ancestors
            common = common.parent_path();
        }
    }
    return common;
}

/// The walk of @p root: DICOM candidates and one scan per file of the other formats.
struct TreeFiles {
    std::vector<fs::path> dicom;
    std::vector<FoundScan> others;
};

TreeFiles listTree(const fs::path& root, const std::vector<fs::path>& skip) {
    std::error_code ec;
    if (!fs::is_directory(root, ec)) {
        throw IoError(root.string() + ": expected a folder of scans, found " +
                      (fs::exists(root, ec) ? "a file" : "nothing"));
    }
    std::set<fs::path> skipped;
    for (const fs::path& s : skip) {
        std::error_code sec;
        const fs::path c = fs::weakly_canonical(s, sec);
        if (!sec) skipped.insert(c);
    }
    TreeFiles out;
    fs::recursive_directory_iterator it(root, fs::directory_options::skip_permission_denied, ec);
    if (ec) {
        throw IoError(root.string() +
                      ": expected a readable folder, found an error: " + ec.message());
    }
    for (const fs::recursive_directory_iterator end; it != end; it.increment(ec)) {
        if (ec) break;
        std::error_code fec;
        if (it->is_directory(fec)) {
            if (!skipped.empty() && skipped.count(fs::weakly_canonical(it->path(), fec)))
                it.disable_recursion_pending();
            continue;
        }
        if (!it->is_regular_file(fec)) continue;
        const Format f = detectFormat(it->path());
        if (f == Format::Dicom) {
            out.dicom.push_back(it->path());
        } else if (f == Format::Nifti || f == Format::Nrrd || f == Format::MetaImage) {
            FoundScan s;
            s.format = f;
            s.imageCount = 1;
            s.files = {it->path()};
            s.folder = it->path().parent_path();
            out.others.push_back(std::move(s));
        }
    }
    if (ec) {
        throw IoError(root.string() +
                      ": expected a readable folder, found an error: " + ec.message());
    }
    return out;
}

}  // namespace

std::vector<FoundScan> findScans(const fs::path& root, const std::vector<fs::path>& skip) {
    TreeFiles tree = listTree(root, skip);
    std::vector<FoundScan> out;
    if (!tree.dicom.empty()) out = detail::dicomPlugin().findScans(tree.dicom);
    for (FoundScan& s : tree.others) out.push_back(std::move(s));
    for (FoundScan& s : out) s.folder = commonFolder(s.files);
    std::sort(out.begin(), out.end(), [](const FoundScan& a, const FoundScan& b) {
        if (a.folder != b.folder) return a.folder < b.folder;
        if (a.seriesUid != b.seriesUid) return a.seriesUid < b.seriesUid;
        return a.files.front() < b.files.front();
    });
    return out;
}

}  // namespace palp::volume
