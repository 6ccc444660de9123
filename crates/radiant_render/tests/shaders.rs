//! Every WGSL shader of the renderer parses and validates with naga, on the CPU (no GPU needed).

#[test]
fn every_shader_validates_with_naga() {
    for (name, source) in radiant_render::shaders() {
        let module = naga::front::wgsl::parse_str(&source)
            .unwrap_or_else(|e| panic!("{name}: {}", e.emit_to_string(&source)));
        naga::valid::Validator::new(
            naga::valid::ValidationFlags::all(),
            naga::valid::Capabilities::empty(),
        )
        .validate(&module)
        .unwrap_or_else(|e| panic!("{name}: {}", e.emit_to_string(&source)));
    }
}
