# Sourced by the scripts that build the real hearts of ../shared/data/real with a septal defect
# (scripts/make-defect-gallery.sh, scripts/make-repair-gallery.sh, tests/bench/run_defect_bench.sh,
# tests/bench/run_repair_bench.sh): what heartprep needs for each case beside its label map, by
# the name of its folder. The HVSMR 2016 hearts label both ventricles' blood alike, so a VSD goes
# --at a point of their septum (the points of tests/test_defect.cpp); the MM-WHS hearts name their
# chambers, and heartprep places it.

declare -A septum_point=([hvsmr16_pat0]=40.7,-14.4,-10.4 [hvsmr16_pat1]=11.4,-25.6,5.2 [hvsmr16_pat5]=26.8,-17.3,-4.9
                         [hvsmr16_pat6]=26.9,-12.1,-20.0)

# label_options CASE: heartprep's --labels for the case's label convention (none for HVSMR 2016's,
# heartprep's default).
label_options() {
  case "$1" in
    mmwhs_ct1002) echo "--labels mmwhs" ;;
    mmwhs_wh) echo "--labels mmwhs-ordinal" ;;
  esac
}

# vsd_options CASE: heartprep build's options for a ventricular septal defect in the case; status
# 1 (nothing printed) for a case with no place known for one.
vsd_options() {
  case "$1" in
    mmwhs_ct1002 | mmwhs_wh) echo "$(label_options "$1") --defect vsd" ;;
    *) [ -n "${septum_point[$1]:-}" ] || return 1; echo "--defect vsd --at=${septum_point[$1]}" ;;
  esac
}
