-- Issue 12: every field of the result document carries its unit in its name.
-- Renames the keys of stored result documents (measurements and fits) so that
-- old and new documents read the same; values are moved unchanged.
--   stiffness.coefficients           -> stiffness.coefficients_n_per_m_pow_i_plus_1
--   stiffness.coefficients_se        -> stiffness.coefficients_se_n_per_m_pow_i_plus_1
--   stiffness.coefficients_n_per_mm  -> stiffness.coefficients_n_per_mm_pow_i_plus_1
--   small_signal.area_per_mic_unit_m2_per_v -> small_signal.force_per_mic_v_n_per_v (it holds N/V)
--   diagnostics.{base_model,final_model}.stiffness_coefficients
--                                    -> ...stiffness_coefficients_n_per_m_pow_i_plus_1

UPDATE measurements SET result_json = json_set(json_remove(result_json, '$.stiffness.coefficients'),
    '$.stiffness.coefficients_n_per_m_pow_i_plus_1', json_extract(result_json, '$.stiffness.coefficients'))
 WHERE result_json IS NOT NULL AND json_valid(result_json) AND json_type(result_json, '$.stiffness.coefficients') IS NOT NULL;
UPDATE measurements SET result_json = json_set(json_remove(result_json, '$.stiffness.coefficients_se'),
    '$.stiffness.coefficients_se_n_per_m_pow_i_plus_1', json_extract(result_json, '$.stiffness.coefficients_se'))
 WHERE result_json IS NOT NULL AND json_valid(result_json) AND json_type(result_json, '$.stiffness.coefficients_se') IS NOT NULL;
UPDATE measurements SET result_json = json_set(json_remove(result_json, '$.stiffness.coefficients_n_per_mm'),
    '$.stiffness.coefficients_n_per_mm_pow_i_plus_1', json_extract(result_json, '$.stiffness.coefficients_n_per_mm'))
 WHERE result_json IS NOT NULL AND json_valid(result_json) AND json_type(result_json, '$.stiffness.coefficients_n_per_mm') IS NOT NULL;
UPDATE measurements SET result_json = json_set(json_remove(result_json, '$.small_signal.area_per_mic_unit_m2_per_v'),
    '$.small_signal.force_per_mic_v_n_per_v', json_extract(result_json, '$.small_signal.area_per_mic_unit_m2_per_v'))
 WHERE result_json IS NOT NULL AND json_valid(result_json) AND json_type(result_json, '$.small_signal.area_per_mic_unit_m2_per_v') IS NOT NULL;
UPDATE measurements SET result_json = json_set(json_remove(result_json, '$.diagnostics.base_model.stiffness_coefficients'),
    '$.diagnostics.base_model.stiffness_coefficients_n_per_m_pow_i_plus_1', json_extract(result_json, '$.diagnostics.base_model.stiffness_coefficients'))
 WHERE result_json IS NOT NULL AND json_valid(result_json) AND json_type(result_json, '$.diagnostics.base_model.stiffness_coefficients') IS NOT NULL;
UPDATE measurements SET result_json = json_set(json_remove(result_json, '$.diagnostics.final_model.stiffness_coefficients'),
    '$.diagnostics.final_model.stiffness_coefficients_n_per_m_pow_i_plus_1', json_extract(result_json, '$.diagnostics.final_model.stiffness_coefficients'))
 WHERE result_json IS NOT NULL AND json_valid(result_json) AND json_type(result_json, '$.diagnostics.final_model.stiffness_coefficients') IS NOT NULL;

UPDATE fits SET result_json = json_set(json_remove(result_json, '$.stiffness.coefficients'),
    '$.stiffness.coefficients_n_per_m_pow_i_plus_1', json_extract(result_json, '$.stiffness.coefficients'))
 WHERE json_valid(result_json) AND json_type(result_json, '$.stiffness.coefficients') IS NOT NULL;
UPDATE fits SET result_json = json_set(json_remove(result_json, '$.stiffness.coefficients_se'),
    '$.stiffness.coefficients_se_n_per_m_pow_i_plus_1', json_extract(result_json, '$.stiffness.coefficients_se'))
 WHERE json_valid(result_json) AND json_type(result_json, '$.stiffness.coefficients_se') IS NOT NULL;
UPDATE fits SET result_json = json_set(json_remove(result_json, '$.stiffness.coefficients_n_per_mm'),
    '$.stiffness.coefficients_n_per_mm_pow_i_plus_1', json_extract(result_json, '$.stiffness.coefficients_n_per_mm'))
 WHERE json_valid(result_json) AND json_type(result_json, '$.stiffness.coefficients_n_per_mm') IS NOT NULL;
UPDATE fits SET result_json = json_set(json_remove(result_json, '$.small_signal.area_per_mic_unit_m2_per_v'),
    '$.small_signal.force_per_mic_v_n_per_v', json_extract(result_json, '$.small_signal.area_per_mic_unit_m2_per_v'))
 WHERE json_valid(result_json) AND json_type(result_json, '$.small_signal.area_per_mic_unit_m2_per_v') IS NOT NULL;
UPDATE fits SET result_json = json_set(json_remove(result_json, '$.diagnostics.base_model.stiffness_coefficients'),
    '$.diagnostics.base_model.stiffness_coefficients_n_per_m_pow_i_plus_1', json_extract(result_json, '$.diagnostics.base_model.stiffness_coefficients'))
 WHERE json_valid(result_json) AND json_type(result_json, '$.diagnostics.base_model.stiffness_coefficients') IS NOT NULL;
UPDATE fits SET result_json = json_set(json_remove(result_json, '$.diagnostics.final_model.stiffness_coefficients'),
    '$.diagnostics.final_model.stiffness_coefficients_n_per_m_pow_i_plus_1', json_extract(result_json, '$.diagnostics.final_model.stiffness_coefficients'))
 WHERE json_valid(result_json) AND json_type(result_json, '$.diagnostics.final_model.stiffness_coefficients') IS NOT NULL;
