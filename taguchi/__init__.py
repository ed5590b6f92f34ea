"""Taguchi method: orthogonal arrays, S/N ratios, analysis and the iterative tuning of PD gains."""
from taguchi.analysis import (
    AnovaTable,
    ResponseTable,
    TaguchiAnalysis,
    analyze,
    anova,
    best_levels,
    predict_sn,
    response_table,
)
from taguchi.arrays import (
    OrthogonalArray,
    array_for,
    available_arrays,
    check_orthogonal_array,
    get_array,
    is_balanced,
    is_pairwise_orthogonal,
    to_design,
)
from taguchi.direct import DirectResult, direct_tune
from taguchi.sn import (
    LOSS_FLOOR,
    SN_CEILING_DB,
    SN_RATIOS,
    larger_the_better,
    nominal_the_best,
    nominal_the_best_type2,
    quadratic_loss,
    smaller_the_better,
    sn_ratio,
    sn_ratios,
    sn_target,
)
from taguchi.robust import (
    NoiseFactor,
    PlantNoiseObjective,
    RobustConfig,
    RobustResult,
    WorstCase,
    noise_grid,
    robust_tune,
    worst_case,
)
from taguchi.tuning import GainObjective, TaguchiIteration, TaguchiResult, TuningConfig, taguchi_tune

__all__ = [
    "OrthogonalArray", "get_array", "array_for", "available_arrays", "is_balanced",
    "is_pairwise_orthogonal", "check_orthogonal_array", "to_design",
    "smaller_the_better", "larger_the_better", "nominal_the_best", "nominal_the_best_type2",
    "quadratic_loss", "sn_target", "sn_ratio", "sn_ratios", "SN_RATIOS", "LOSS_FLOOR", "SN_CEILING_DB",
    "ResponseTable", "AnovaTable", "TaguchiAnalysis", "response_table", "anova", "best_levels",
    "predict_sn", "analyze",
    "GainObjective", "TuningConfig", "TaguchiIteration", "TaguchiResult", "taguchi_tune",
    "DirectResult", "direct_tune",
    "NoiseFactor", "RobustConfig", "RobustResult", "WorstCase", "PlantNoiseObjective", "noise_grid",
    "robust_tune", "worst_case",
]
