//! Migration 0150 renames the unit-less keys of stored result documents
//! (issue 12) without changing any value.

use serde_json::{json, Value};
use sqlx::{Connection, Row, SqliteConnection};

#[tokio::test]
async fn stored_documents_get_the_unit_field_names_with_values_unchanged() {
    let mut c = SqliteConnection::connect("sqlite::memory:").await.unwrap();
    // Only the columns the migration touches.
    sqlx::raw_sql(
        "CREATE TABLE measurements (seq INTEGER PRIMARY KEY, result_json TEXT);
         CREATE TABLE fits (seq INTEGER PRIMARY KEY, result_json TEXT NOT NULL);",
    )
    .execute(&mut c)
    .await
    .unwrap();
    let old = json!({
        "small_signal": {"k0_n_per_m": 2400.0, "area_per_mic_unit_m2_per_v": 0.0137},
        "stiffness": {"order": 2, "coefficients": [2400.0, 1.2e5, 3.6e7],
                      "coefficients_se": [1.0, 2.0, 3.0],
                      "coefficients_n_per_mm": [2.4, 0.12, 0.036]},
        "diagnostics": {"base_model": {"stiffness_coefficients": [2401.0]},
                        "final_model": {"stiffness_coefficients": [2399.0, 5.0]}}
    });
    for sql in [
        "INSERT INTO measurements (result_json) VALUES (?)",
        "INSERT INTO fits (result_json) VALUES (?)",
    ] {
        sqlx::query(sql)
            .bind(old.to_string())
            .execute(&mut c)
            .await
            .unwrap();
    }
    // A failed analysis stores no document; the migration must leave it alone.
    sqlx::query("INSERT INTO measurements (result_json) VALUES (NULL)")
        .execute(&mut c)
        .await
        .unwrap();
    sqlx::raw_sql(include_str!(
        "../../crates/store/migrations/0150_unit_field_names.sql"
    ))
    .execute(&mut c)
    .await
    .unwrap();
    for (table, sql) in [
        (
            "measurements",
            "SELECT result_json FROM measurements WHERE result_json IS NOT NULL",
        ),
        ("fits", "SELECT result_json FROM fits"),
    ] {
        let row = sqlx::query(sql).fetch_one(&mut c).await.unwrap();
        let doc: Value = serde_json::from_str(&row.get::<String, _>(0)).unwrap();
        let s = &doc["stiffness"];
        assert_eq!(
            s["coefficients_n_per_m_pow_i_plus_1"],
            json!([2400.0, 1.2e5, 3.6e7])
        );
        assert_eq!(
            s["coefficients_se_n_per_m_pow_i_plus_1"],
            json!([1.0, 2.0, 3.0])
        );
        assert_eq!(
            s["coefficients_n_per_mm_pow_i_plus_1"],
            json!([2.4, 0.12, 0.036])
        );
        assert_eq!(s["order"], json!(2));
        for gone in ["coefficients", "coefficients_se", "coefficients_n_per_mm"] {
            assert!(s.get(gone).is_none(), "{table}: {gone} still there");
        }
        assert_eq!(
            doc["small_signal"]["force_per_mic_v_n_per_v"],
            json!(0.0137)
        );
        assert!(doc["small_signal"]
            .get("area_per_mic_unit_m2_per_v")
            .is_none());
        assert_eq!(doc["small_signal"]["k0_n_per_m"], json!(2400.0));
        let d = &doc["diagnostics"];
        assert_eq!(
            d["base_model"]["stiffness_coefficients_n_per_m_pow_i_plus_1"],
            json!([2401.0])
        );
        assert_eq!(
            d["final_model"]["stiffness_coefficients_n_per_m_pow_i_plus_1"],
            json!([2399.0, 5.0])
        );
        assert!(d["final_model"].get("stiffness_coefficients").is_none());
    }
    let nulls: i64 = sqlx::query("SELECT COUNT(*) FROM measurements WHERE result_json IS NULL")
        .fetch_one(&mut c)
        .await
        .unwrap()
        .get(0);
    assert_eq!(nulls, 1);
}
