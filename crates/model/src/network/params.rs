//! Host-side access to a module's parameters, in visit order: read values and gradients out,
//! write new values in. The optimiser, the EMA and checkpoints work on these flat vectors,
//! which makes checkpoints exact and resume bit-for-bit.

use burn::module::{ModuleMapper, ModuleVisitor, Param, ParamId};
use burn::optim::GradientsParams;
use burn::prelude::*;

/// A tensor's values on the host, as f32.
pub fn host<const D: usize>(t: Tensor<D>) -> Vec<f32> {
    // into_vec takes the buffer over where it can (no copy of the whole tensor).
    t.into_data().convert::<f32>().try_into_vec::<f32>().expect("float tensor")
}

struct ParamValues(Vec<(Vec<usize>, Vec<f32>)>);
impl ModuleVisitor for ParamValues {
    fn visit_float<const D: usize>(&mut self, p: &Param<Tensor<D>>) {
        let t = p.val();
        self.0.push((t.dims().to_vec(), host(t)));
    }
}

/// (shape, values) of every float parameter.
pub fn values<M: Module>(m: &M) -> Vec<(Vec<usize>, Vec<f32>)> {
    let mut v = ParamValues(Vec::new());
    m.visit(&mut v);
    v.0
}

struct Shapes(Vec<Vec<usize>>);
impl ModuleVisitor for Shapes {
    fn visit_float<const D: usize>(&mut self, p: &Param<Tensor<D>>) {
        self.0.push(p.val().dims().to_vec());
    }
}

/// The shape of every float parameter (visit order), without reading any value.
pub fn shapes<M: Module>(m: &M) -> Vec<Vec<usize>> {
    let mut v = Shapes(Vec::new());
    m.visit(&mut v);
    v.0
}

struct Grads<'a> {
    grads: &'a GradientsParams,
    out: Vec<Vec<f32>>,
}
impl ModuleVisitor for Grads<'_> {
    fn visit_float<const D: usize>(&mut self, p: &Param<Tensor<D>>) {
        let g = self
            .grads
            .get::<D>(p.id)
            .map(host)
            .unwrap_or_else(|| vec![0.0; p.val().shape().num_elements()]);
        self.out.push(g);
    }
}

/// Gradients of every float parameter (zeros where a parameter got none).
pub fn grads<M: Module>(m: &M, grads: &GradientsParams) -> Vec<Vec<f32>> {
    let mut v = Grads { grads, out: Vec::new() };
    m.visit(&mut v);
    v.out
}

struct Register<'a> {
    vals: std::slice::Iter<'a, Vec<f32>>,
    out: GradientsParams,
}
impl ModuleVisitor for Register<'_> {
    fn visit_float<const D: usize>(&mut self, p: &Param<Tensor<D>>) {
        let v = self.vals.next().expect("one gradient per parameter").clone();
        let t = p.val();
        let g = Tensor::<D>::from_data(TensorData::new(v, t.shape()), &t.inner().device());
        self.out.register(p.id, g);
    }
}

/// Gradients (visit order, as `grads` gives them) as Burn's gradients of `m`'s parameters, on
/// each parameter's device without autodiff.
pub fn gradients<M: Module>(m: &M, vals: &[Vec<f32>]) -> GradientsParams {
    let mut r = Register { vals: vals.iter(), out: GradientsParams::new() };
    m.visit(&mut r);
    r.out
}

struct Load<'a> {
    vals: &'a [Vec<f32>],
    i: usize,
}
impl ModuleMapper for Load<'_> {
    fn map_float<const D: usize>(&mut self, p: Param<Tensor<D>>) -> Param<Tensor<D>> {
        let (id, t, mapper): (ParamId, Tensor<D>, _) = p.consume();
        let device = t.device();
        let shape = t.shape();
        let v = &self.vals[self.i];
        assert_eq!(
            v.len(),
            shape.num_elements(),
            "parameter {} has {} values, expected {}",
            self.i,
            v.len(),
            shape.num_elements()
        );
        self.i += 1;
        // TensorData::new takes the vector over: one memcpy, not an element-wise conversion
        // (which was ~4% of a paper training step).
        let mut new = Tensor::<D>::from_data(TensorData::new(v.to_vec(), shape), &device);
        if device.is_autodiff() {
            new = new.require_grad();
        }
        Param::from_mapped_value(id, new, mapper)
    }
}

/// The module with its parameters replaced by `vals` (visit order).
pub fn load<M: Module>(m: M, vals: &[Vec<f32>]) -> M {
    let mut l = Load { vals, i: 0 };
    let m = m.map(&mut l);
    assert_eq!(l.i, vals.len(), "parameter count mismatch");
    m
}

struct Names {
    path: Vec<String>,
    out: Vec<String>,
}
impl ModuleVisitor for Names {
    fn enter_module(&mut self, name: &str, _container: &str) {
        self.path.push(name.to_string());
    }
    fn exit_module(&mut self, _name: &str, _container: &str) {
        self.path.pop();
    }
    fn visit_float<const D: usize>(&mut self, _p: &Param<Tensor<D>>) {
        self.out.push(self.path.join("."));
    }
}

/// The module path of every float parameter (visit order), e.g. `decoder.layers.0.ffn.weight`.
pub fn names<M: Module>(m: &M) -> Vec<String> {
    let mut v = Names { path: Vec::new(), out: Vec::new() };
    m.visit(&mut v);
    v.out
}
