(function(){
  // click-to-enlarge: every img.zoom opens in the lightbox dialog; a click or Escape closes it
  const box=document.getElementById('lightbox');
  if(box){const big=box.querySelector('img'),caption=box.querySelector('figcaption');
    document.querySelectorAll('img.zoom').forEach(img=>img.addEventListener('click',()=>{
      big.src=img.src; big.alt=img.alt; caption.textContent=img.alt; box.showModal();}));
    box.addEventListener('click',()=>box.close());}
  // the 3D view: the GLB comes as a data: URL from models/<hash>.js (loads from disk as well as a server)
  const viewer=document.getElementById('viewer');
  if(viewer){const note=document.getElementById('viewer-note');
    if(!window.customElements||!customElements.get('model-viewer')||!window.photoshapeModel){
      viewer.hidden=true; if(note) note.textContent='The 3D view could not start here; the GLB is in the downloads.';}
    else{viewer.addEventListener('error',()=>{if(note) note.textContent='The 3D view could not load the model; the GLB is in the downloads.';});
      viewer.src=window.photoshapeModel;}}
})();
