/* The example's weights blob and recorded inputs, linked into flash from the files named at
 * build time (-DNEMM_EXAMPLE_BLOB="path", -DNEMM_EXAMPLE_INPUTS="path"). An ECU build
 * would place the blob the same way, or in a flash region of its own. The blob starts
 * 4-byte aligned (`.balign 4`): level tables read its tables in place and refuse an
 * unaligned blob (NEMM_E_LEVELS_UNALIGNED). */
    .section .rodata.nemm_example, "a", %progbits
    .balign 4
    .global nemm_example_blob
nemm_example_blob:
    .incbin NEMM_EXAMPLE_BLOB
    .global nemm_example_blob_end
nemm_example_blob_end:
    .balign 4
    .global nemm_example_inputs
nemm_example_inputs:
    .incbin NEMM_EXAMPLE_INPUTS
    .global nemm_example_inputs_end
nemm_example_inputs_end:
