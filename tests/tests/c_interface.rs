//! The C interface (`nemm-c`) instantiates the estimator as the firmware does: the same
//! parameter capacity, table segments and table bound, so that a C program and the firmware
//! give the same forces for the same blob (`cargo xtask c-test` compares them in QEMU).

#[test]
fn the_c_interface_has_the_firmwares_capacities() {
    assert_eq!(nemm_c::NEMM_PARAM_CAPACITY, nemm_firmware::PARAM_CAPACITY);
    assert_eq!(nemm_c::NEMM_TABLE_SEGMENTS, nemm_firmware::TABLE_SEGMENTS);
    assert_eq!(
        nemm_c::NEMM_TABLE_MAX_REL_ERROR.to_bits(),
        nemm_firmware::TABLE_MAX_REL_ERROR.to_bits()
    );
    // The table mode of the C interface is the firmware's `eval_mode(true)`.
    assert_eq!(
        nemm_firmware::eval_mode(true),
        nemm_core::EvalMode::Table(nemm_core::TableConfig::new(
            nemm_c::NEMM_TABLE_MAX_REL_ERROR
        ))
    );
}
