//! Results: Table 4 / 5 and the JSON report ([`tables`]), the identifiability of the level
//! and the whole-run errors per level and condition ([`identify`]), the comparison with the
//! virtual bench's reference coefficients ([`reference`](mod@reference)), the degradation
//! signature (Fig. 5, measured against modelled: [`signature`]), the degradation targets
//! each against its bar ([`targets`]), the whole-run
//! predictions the loop figures draw ([`predictions`]), the figures ([`figures`],
//! [`bench_plots`]) drawn with the plotting helpers ([`plot`]), the description of a
//! weights blob ([`inspect`]), and the online alpha observer on recorded runs
//! ([`diagnose`]): its accuracy ([`accuracy`]) and a level step ([`level_step`]).
pub mod accuracy;
pub mod bench_plots;
pub mod diagnose;
pub mod figures;
pub mod identify;
pub mod inspect;
pub mod level_step;
pub mod plot;
pub mod predictions;
pub mod reference;
pub mod signature;
pub mod tables;
pub mod targets;
