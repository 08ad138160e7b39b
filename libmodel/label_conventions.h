/// @file label_conventions.h
/// @brief Label conventions of public heart segmentations, by name (`--labels mmwhs`): what each
/// label value is, and which labels are the chambers' blood, so a label map that carries no
/// names speaks in structures (tissue, cavities, the septum between two chambers).
///
///   hvsmr2016      HVSMR 2016 (Pace et al., MICCAI 2015): 1 myocardium, 2 blood pool (every chamber and vessel)
///   mmwhs          MM-WHS 2017 (Zhuang et al., MedIA 2019): 205 myocardium (the left ventricle's wall
///                  with the septum), 420 left atrium, 500 left ventricle, 550 right atrium,
///                  600 right ventricle, 820 ascending aorta, 850 pulmonary artery (blood)
///   mmwhs-ordinal  the same structures numbered 1-7 in the order of their codes (1 myocardium,
///                  2 left atrium, 3 left ventricle, 4 right atrium, 5 right ventricle, 6 aorta,
///                  7 pulmonary artery), as many MM-WHS derivatives store them
#pragma once

#include "libmodel/segment_names.h"
#include "libmodel/walls.h"

#include <set>
#include <string>
#include <vector>

namespace heartsim {

struct LabelConvention {
    std::string name;        ///< as given to --labels
    std::string title;       ///< "MM-WHS 2017", for messages
    SegmentNames names;      ///< label -> segment name (muscle and blood are told apart by these names)
    int myocardium = 0;      ///< the heart muscle label
    /// The chambers' blood labels; 0 where the convention does not tell the chambers apart
    /// (HVSMR 2016: one blood pool).
    int left_atrium = 0, left_ventricle = 0, right_atrium = 0, right_ventricle = 0;
    int aorta = 0;           ///< the aorta's blood (0: not labelled apart)
    int pulmonary_artery = 0;///< the pulmonary artery's blood (0: not labelled apart)
    std::vector<int> blood;  ///< every blood-filled label: the cavities when none are chosen
    /// Which walls the convention labels, in words, for summaries ("" where it says nothing).
    std::string labelled_walls;
    /// Whether the chambers are labelled apart (a septum can be found without a point).
    bool chambers() const { return left_ventricle != 0 && right_ventricle != 0; }
};

/// The walls to grow where the convention labels blood without its wall (walls.h): MM-WHS's right
/// ventricle's free wall, left ventricle where its labelled wall leaves its blood bare, atria, aorta and
/// pulmonary artery; HVSMR's one blood pool. Their grown voxels are labelled `first_label`,
/// `first_label` + 1, … in that order. Names: "right ventricle free wall (grown)", ...
std::vector<WallStructure> convention_walls(const LabelConvention& convention, const WallThicknesses& thickness, int first_label);

/// Every known convention, in the order above.
const std::vector<LabelConvention>& label_conventions();

/// The convention named `name` (case-insensitive), or nullptr.
const LabelConvention* find_label_convention(const std::string& name);

/// "hvsmr2016, mmwhs, mmwhs-ordinal": for help texts and messages.
std::string label_convention_names();

/// The convention whose labels are exactly the non-zero labels `present` of a volume (every one
/// of its labels occurs, and no other), or nullptr. A suggestion only: a volume may happen to use
/// the same numbers for other structures.
const LabelConvention* matching_label_convention(const std::set<int>& present);

}  // namespace heartsim
