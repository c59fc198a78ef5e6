#pragma once
/// @file
/// What the hand felt over the palpated patch, for `palp palpate --json`: where the stiffness
/// felt was highest, and how deep the hard structure under it lies by the coupling's own rays,
/// so a study can set feel against anatomy.

#include <nlohmann/json.hpp>
#include <span>

#include "palp/haptics/session.h"
#include "palpate_setup.h"

namespace palp::tool {

/// Bins the contact ticks from @p pressedFrom (s) on over frame @p f in square cells of
/// @p cellM (m): per cell the mean stiffness felt (N/m), the mean centre-ray length L to the
/// hard structure (m; L_max where the rays found none) and the mean proxy position. Returns
/// The stiffest cell: the largest mean stiffness, ties (a clamped k) to the shortest L.
///   {"cell_mm", "cells" (with >= 3 ticks), "stiffest": {"stiffness_npm", "at_mm" (mean proxy
///   position, on the skin), "lateral_mm" (u, v from the frame's centre), "hard_depth_mm",
///   "cells_within_1_percent"}, "stiffness_vs_hard_depth_spearman"}
/// or {"cells": 0} when no cell has enough ticks.
nlohmann::json feltSummary(std::span<const haptics::Snapshot> snaps, const PathFrame& f,
                           double cellM, double pressedFrom);

/// Spearman's rank correlation of @p x and @p y (same size >= 2; ties share their mean rank);
/// NaN when either is constant.
double spearman(std::span<const double> x, std::span<const double> y);

}  // namespace palp::tool
